"""Physics backends: batched observations, deterministic replay, and the batched-simulation (GPU) path
checked against a plain task env."""

import numpy as np
import pytest

from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
from sb3_memret.physics.backends import BatchedSimPhysics, InProcessPhysics, ResetRequest, TaskRunner
from sb3_memret.tasks.base import EnvFrame
from sb3_memret.common.obs_trees import select_obs, stack_obs
from sb3_memret.evaluation.rollout import task_env_kwargs
from sb3_memret.tasks import make_task

KWARGS = task_env_kwargs(ScriptedDrawerController(), "none", make_task("drawer"))


def chunk(rng: np.random.Generator, steps: int) -> np.ndarray:
    return rng.uniform(-0.5, 0.5, size=(steps, 7)).astype(np.float32)


def assert_same_frame(a: EnvFrame, b: EnvFrame) -> None:
    assert (a.steps, a.terminated, a.truncated, a.success) == (b.steps, b.terminated, b.truncated, b.success)
    assert a.potential == pytest.approx(b.potential, abs=1e-6)
    for name, value in vars(a.state).items():
        if value.dtype.kind in "US":
            np.testing.assert_array_equal(value, getattr(b.state, name), err_msg=name)
        else:
            np.testing.assert_allclose(value, getattr(b.state, name), atol=1e-5, err_msg=name)
    np.testing.assert_allclose(a.obs["agent"]["eef_state"], b.obs["agent"]["eef_state"], atol=1e-5)
    np.testing.assert_allclose(a.obs["extra"]["target_detection"], b.obs["extra"]["target_detection"], atol=1e-5)


def test_stack_and_select_are_inverse():
    frames = [{"agent": {"eef_state": np.full((1, 8), i, np.float32)}, "extra": {"x": np.full((1, 3), -i)}}
              for i in range(3)]
    batched = stack_obs(frames)
    assert batched["agent"]["eef_state"].shape == (3, 8) and batched["extra"]["x"].shape == (3, 3)
    for i, frame in enumerate(frames):
        np.testing.assert_array_equal(select_obs(batched, i)["extra"]["x"], frame["extra"]["x"])


def test_a_replayed_episode_lands_where_it_was():
    """What a restarted Ray actor relies on: the same seed and chunks give the same state."""
    rng = np.random.default_rng(0)
    chunks = [chunk(rng, 8) for _ in range(4)]
    first, second = TaskRunner(KWARGS, 400, "drawer"), TaskRunner(KWARGS, 400, "drawer")
    try:
        first.reset(11, {"target_layer": 3})
        for c in chunks:
            played = first.execute(c)
        assert_same_frame(second.replay(11, {"target_layer": 3}, chunks), played)
    finally:
        first.close()
        second.close()


def test_the_batched_simulation_path_plays_as_a_plain_env():
    """``BatchedSimPhysics`` is the GPU path (one ManiSkill env, num_envs=N, sim_backend="gpu"). ManiSkill's CPU
    simulation holds one env, so here it runs at N = 1 on the CPU against a plain task env: the same frames after
    a reset, after chunks, and when the episode ends inside a chunk (20-step limit, chunks of 8)."""
    rng = np.random.default_rng(1)
    batched = BatchedSimPhysics(1, {**KWARGS, "sim_backend": "cpu"}, 20, "drawer")
    plain = InProcessPhysics(1, KWARGS, 20, "drawer")
    try:
        request = [ResetRequest(0, 5, {"target_layer": 2})]
        assert_same_frame(batched.reset(request)[0], plain.reset(request)[0])
        for steps in (8, 8, 8):
            c = chunk(rng, steps)
            a, b = batched.execute({0: c})[0], plain.execute({0: c})[0]
            assert_same_frame(a, b)
        assert (a.steps, a.truncated) == (4, True)
        assert_same_frame(batched.reset(request)[0], plain.reset(request)[0])  # a fresh episode after the end
    finally:
        batched.close()
        plain.close()


def test_the_writer_perceives_its_window_only_and_the_cameras_render_only_what_is_read():
    """RememberColor3's writer perceives every step of its window (MIKASA's longest cue and one step); after it, the
    camera renders only for the next decision. The same episode with the window lifted: equal frames, and every
    percept after the window is None (no later frame shows the cue)."""
    pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason="needs mikasa-robo-suite")
    from sb3_memret.physics.sensor_gate import SensorGate
    from sb3_memret.tasks import make_task

    task = make_task("RememberColor3-VLA-v0")
    kwargs = task.env_kwargs(needs_images=False, render_backend="cpu")
    windowed, everywhere = (TaskRunner(kwargs, task.max_control_steps, task) for _ in range(2))
    everywhere.window = None
    renders = {}
    for name, runner in (("windowed", windowed), ("everywhere", everywhere)):
        gate, renders[name] = SensorGate.of(runner.env), 0
        render = gate._render

        def counted(*args, _name=name, _render=render, **kwargs):
            renders[_name] += 1
            return _render(*args, **kwargs)

        gate._render = counted
    try:
        assert windowed.window == 6
        played = {name: [runner.reset(5001, {})] for name, runner in (("windowed", windowed),
                                                                     ("everywhere", everywhere))}
        zeros = np.zeros((task.replan_every, 7), np.float32)
        while not played["windowed"][-1].truncated:
            for name, runner in (("windowed", windowed), ("everywhere", everywhere)):
                played[name].append(runner.execute(zeros))
        steps = 0
        for a, b in zip(played["windowed"], played["everywhere"]):
            assert (a.steps, a.success, a.truncated) == (b.steps, b.success, b.truncated)
            np.testing.assert_array_equal(a.obs["agent"]["qpos"], b.obs["agent"]["qpos"])
            seen = max(0, min(len(b.percepts), task.perception_window(windowed.env) - steps - (a.steps > 0)))
            assert a.percepts == b.percepts[:seen] and all(p is None for p in b.percepts[seen:]), steps
            steps += a.steps
        assert any(p is not None for frame in played["windowed"] for p in frame.percepts)  # the cue was read
        decisions = len(played["windowed"]) - 1
        assert renders["everywhere"] == 1 + steps  # the reset and every step
        assert renders["windowed"] < renders["everywhere"] and renders["windowed"] <= 6 + decisions
    finally:
        windowed.close()
        everywhere.close()
