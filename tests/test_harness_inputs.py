"""The policy side of the benchmark reads MIKASA's harness inputs alone: its 7-D proprioception derived as the
harness derives it, the policy-side view rebuilt from rgb and proprio, and the guard that fails any read of the
simulator from the writer, bank, retriever or a protocol controller while the agent acts."""

from __future__ import annotations

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from mikasa_robo_suite.vla.utils.wrappers import ConvertJointsToEEFXyzRpyGripperWrapper  # noqa: E402

from sb3_memret.benchmark import harness  # noqa: E402
from sb3_memret.benchmark.agent import MemoryAgent  # noqa: E402
from sb3_memret.benchmark.guard import SimulatorGuard, SimulatorRead, benchmark_reads  # noqa: E402
from sb3_memret.benchmark.view import policy_view  # noqa: E402
from sb3_memret.controllers.harness_proprio import (HARNESS_PROPRIO_NAMES, harness_proprio, quat_to_rpy,  # noqa: E402
                                                    rpy_to_quat, with_harness_proprio)
from sb3_memret.controllers.learned.processing import harness_inputs  # noqa: E402
from sb3_memret.controllers.observation import STATE_KEY  # noqa: E402
from sb3_memret.tasks.mikasa.remember.color import RememberColorTask  # noqa: E402

TASK = "RememberColor3-VLA-v0"
DEV_SEED = 5000  # development seeds only: the protocol's stay unseen


def test_roll_pitch_yaw_is_the_harness_formula_and_inverts():
    rng = np.random.default_rng(0)
    quat = rng.normal(size=(500, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat[quat[:, 0] < 0] *= -1
    rpy = quat_to_rpy(quat)
    harness = ConvertJointsToEEFXyzRpyGripperWrapper._quat_wxyz_to_rpy_np(quat.astype(np.float32))
    np.testing.assert_allclose(rpy, harness, atol=1e-5)
    np.testing.assert_allclose(rpy_to_quat(rpy), quat, atol=1e-9)


def test_the_harness_columns_are_appended_or_their_sources_named():
    names = ("qpos_7", "qpos_8", "tcp_x", "tcp_y", "tcp_z", "tcp_qw", "tcp_qx", "tcp_qy", "tcp_qz", "cube_x")
    states = np.array([[0.01, 0.02, 0.1, 0.2, 0.3, 1.0, 0.0, 0.0, 0.0, 9.0]])
    extended, extended_names = with_harness_proprio(states, names)
    assert extended_names == names + HARNESS_PROPRIO_NAMES
    np.testing.assert_allclose(extended[0, -7:], [0.1, 0.2, 0.3, 0, 0, 0, 0.03], atol=1e-7)
    with pytest.raises(ValueError, match=r"without \['qpos_8'\]"):
        with_harness_proprio(np.delete(states, 1, axis=1), names[:1] + names[2:])


@pytest.fixture(scope="module")
def harness_env():
    env = harness.make_env(TASK)
    yield env
    env.close()


def test_the_harness_proprio_is_what_the_hand_and_fingers_give_and_the_view_gives_it_back(harness_env):
    """What finetune derives from a demonstration's hand pose and fingers is the harness's ``proprio``, and the
    policy-side view rebuilt from it gives a harness controller the same seven numbers."""
    obs, _ = harness_env.reset(seed=DEV_SEED)
    rng = np.random.default_rng(0)
    for _ in range(4):
        agent = harness_env.unwrapped.agent
        derived = harness_proprio(np.asarray(agent.tcp.pose.raw_pose), np.asarray(agent.robot.get_qpos())[:, 7:9])
        given = np.asarray(obs["proprio"]).reshape(1, 7)
        np.testing.assert_allclose(derived, given, atol=1e-5)
        view = policy_view(obs)
        np.testing.assert_allclose(harness_inputs(view, ())[STATE_KEY], given, atol=1e-5)
        assert view["sensor_data"]["base_camera"]["rgb"].shape == (1, 128, 128, 3)
        action = np.clip(rng.normal(scale=0.5, size=(1, 7)), -1, 1).astype(np.float32)
        obs, *_ = harness_env.step(action)


def test_the_policy_view_names_what_the_harness_does_not_give(harness_env):
    obs, _ = harness_env.reset(seed=DEV_SEED)
    view = policy_view(obs)
    assert np.isnan(view["agent"]["qpos"][:, :7]).all() and not np.isnan(view["agent"]["qpos"][:, 7:]).any()
    with pytest.raises(KeyError, match="'qvel' is not in the benchmark's policy-side view.*7-D proprioception"):
        view["agent"]["qvel"]
    with pytest.raises(KeyError, match="'cube_positions'"):
        view["extra"]["cube_positions"]


def test_the_guard_refuses_reads_while_acting_except_the_benchmarks_own():
    class Env:
        unwrapped = "the simulator"

    guard = SimulatorGuard(Env())
    assert guard.unwrapped == "the simulator"  # set-up reads pass
    with guard.armed():
        with pytest.raises(SimulatorRead, match="read 'unwrapped' of the harness env while acting"):
            guard.unwrapped
        with benchmark_reads("the episode's truth"):
            assert guard.unwrapped == "the simulator"
    assert guard.unwrapped == "the simulator"
    with pytest.raises(AttributeError, match="does not set 'unwrapped'"):
        guard.unwrapped = None


class PeekingColourTask(RememberColorTask):
    """A writer that reads the cue from the simulator instead of the camera."""

    def perceive(self, env, obs):
        return self.words[int(np.asarray(env.unwrapped.true_color_indices).reshape(-1)[0])]


@pytest.mark.parametrize("condition", ["written", "oracle"])
def test_a_writer_reading_the_simulator_fails_and_the_camera_writer_plays(harness_env, condition):
    """The same episode: the task's own writer (cameras) plays it to the end under every condition; a writer that
    peeks at the simulator is stopped at its first read where the condition writes facts."""
    task = RememberColorTask(TASK)
    agent = MemoryAgent(task, task.expert(), condition, task.replan_every)
    agent.bind(harness_env)
    agent.begin(0)
    assert harness.play_episode(harness_env, agent, DEV_SEED).success_once
    peeking = PeekingColourTask(TASK)
    agent = MemoryAgent(peeking, peeking.expert(), condition, peeking.replan_every)
    agent.bind(harness_env)
    agent.begin(0)
    if condition == "written":
        with pytest.raises(SimulatorRead, match="'unwrapped'"):
            harness.play_episode(harness_env, agent, DEV_SEED)
    else:  # no facts written: the writer never perceives
        assert harness.play_episode(harness_env, agent, DEV_SEED).success_once
