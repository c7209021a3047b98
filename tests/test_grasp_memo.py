"""``physics.grasp_memo``: MIKASA's repeated grasp checks answered once per physics step, with ManiSkill's answers."""

from __future__ import annotations

import pytest
import torch

from mikasa_support import MIKASA_MISSING

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)


def test_the_memo_answers_as_maniskill_does_through_a_whole_episode(monkeypatch):
    """The scripted expert plays BatteriesCheckerEasy-3 (its grasps, inserts and returns) through the harness: every
    grasp check the env makes is answered by the memo and by ManiSkill's own function, and the two always agree;
    the memo answered repeats (two checks of each battery a step), and some answers were grasps."""
    from mani_skill.agents.robots.panda.panda import Panda

    from sb3_memret.benchmark.harness import install_shims
    from sb3_memret.benchmark.runner import Protocol, Unit, _Worker

    install_shims()
    memoised = Panda.is_grasping
    maniskill = memoised.__wrapped__
    seen = {"calls": 0, "grasps": 0, "states": set(), "disagree": 0}

    def checked(self, object, min_force=0.5, max_angle=85):
        answer = memoised(self, object, min_force, max_angle)
        seen["disagree"] += int(not torch.equal(answer, maniskill(self, object, min_force, max_angle)))
        seen["calls"] += 1
        seen["grasps"] += int(answer.any())
        seen["states"].add(getattr(self.scene, "_sb3_memret_physics_steps", 0))
        return answer

    monkeypatch.setattr(Panda, "is_grasping", checked)
    worker = _Worker(Protocol(seed_set="dev", episodes=1, controller="scripted"), None)
    record = worker.play(Unit("BatteriesCheckerEasy-3-VLA-v0", "oracle", 5000))
    assert "error" not in record, record.get("error")
    assert seen["disagree"] == 0 and seen["grasps"] > 0
    assert seen["calls"] >= 2 * 15 * (len(seen["states"]) - 1)  # 15 batteries, evaluate and reward: repeats
