"""scripts/prompt_schedules.py: which fact each decision's prompt carries, and the episodes it plays."""

import numpy as np
import pytest

from sb3_memret.tasks import make_task


@pytest.fixture(scope="module")
def schedules(load_script):
    return load_script("prompt_schedules")


def test_a_schedule_switches_between_the_true_fact_and_a_decoy_at_its_decision(schedules):
    rng = np.random.default_rng(0)
    true, decoys = "the cube was red.", ["the key was blue.", "the cup was red."]
    assert [schedules.fact_at("decoy-then-oracle", d, 2, true, decoys, rng) for d in range(4)] == \
        [decoys[0], decoys[0], true, true]
    assert [schedules.fact_at("oracle-then-decoy", d, 1, true, decoys, rng) for d in range(3)] == \
        [true, decoys[0], decoys[0]]
    drawn = {schedules.fact_at("uniform", d, 0, true, decoys, rng) for d in range(60)}
    assert drawn == {true, *decoys}  # every memory of the bank, the true one among them
    with pytest.raises(ValueError, match="unknown schedule 'sometimes'"):
        schedules.fact_at("sometimes", 0, 0, true, decoys, rng)


def test_the_scripted_expert_succeeds_on_the_true_fact_and_the_uniform_breakdown_counts_it(schedules):
    task = make_task("RememberColor3-VLA-v0")
    records = schedules.play(task, task.expert(), ["oracle", "uniform"], episodes=2, switch=3)
    assert [r["schedule"] for r in records] == ["oracle", "oracle", "uniform", "uniform"]
    assert [r["seed"] for r in records[:2]] == task.development_seeds(2)  # the protocol's test set stays unseen
    oracle = records[:2]
    assert all(r["success"] and all(r["true"]) for r in oracle)
    decisions = len(oracle[0]["true"])
    assert decisions == -(-task.max_control_steps // 4)  # a fact at every replan of 4 steps
    lines = schedules.uniform_breakdown(records, switch=3)
    assert lines[0] == "uniform, by the true fact's count in decisions 3..:"
    counted = sum(int(line.split(" of ")[1]) for line in lines[1:] if " of " in line)
    assert counted == 2
    with pytest.raises(ValueError, match="unknown schedule 'never'"):
        schedules.play(task, task.expert(), ["never"], episodes=1, switch=0)
