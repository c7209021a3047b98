"""Intercept's catching expert on the harness's inputs alone (``scripted-camera``): the ball and the target read from
the base camera, the ball followed while unseen and while in hand, and an episode through MIKASA's harness as a
protocol entry."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, camera_expert_cells, harness_obs as _obs

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT  # noqa: E402
from sb3_memret.tasks.mikasa.intercept.camera_expert import (  # noqa: E402
    CameraInterceptController, HeldBall, read_ball, read_target)
from sb3_memret.tasks.mikasa.intercept.expert import CatchGains  # noqa: E402
from sb3_memret.tasks.mikasa.intercept.task import CUE_FACT, INTERCEPT_INSTRUCTION  # noqa: E402

TASK = "InterceptMedium-VLA-v0"


def test_the_target_and_the_ball_are_read_from_the_base_camera():
    env = make_task(TASK).make_env(obs_mode="rgb")
    try:
        for seed in range(5000, 5004):
            obs, _ = env.reset(seed=seed)
            base = env.unwrapped
            rgb = as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0]
            assert np.linalg.norm(read_target(rgb) - as_numpy(base.goal_region.pose.p).reshape(-1)[:2]) < 0.015
            for _ in range(12):  # the ball comes into view as it rolls
                obs, *_ = env.step(np.zeros(env.action_space.shape))
            seen = read_ball(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0])
            assert np.linalg.norm(seen - as_numpy(base.ball.pose.p).reshape(-1)[:2]) < 0.015
    finally:
        env.close()


def test_an_unseen_ball_rolls_on_from_its_last_sighting_and_a_held_one_goes_with_the_hand():
    gains = CatchGains()
    ball = HeldBall(gains)
    ball.reset(1)
    velocity = np.array([0.0, 0.4])
    assert ball.where(0, np.zeros(3), 0.08, velocity) is None  # never seen
    ball.see(0, np.array([0.1, -0.3]))
    ball.ran(4)
    ball.see(0, None)  # the fingers round it
    assert np.allclose(ball.where(0, np.array([0.3, 0.0, 0.2]), 0.08, velocity),
                       [0.1, -0.3 + 0.4 * 4 * CONTROL_DT, 0.02])
    at = np.array([0.1, -0.3 + 0.4 * 4 * CONTROL_DT, 0.025])
    assert np.allclose(ball.where(0, at, 0.04, velocity), at) and ball.held == [True]  # closed on it
    away = np.array([0.3, 0.1, 0.04])
    assert np.allclose(ball.where(0, away, 0.04, velocity), away)  # carried off, seen or not
    assert ball.where(0, away, 0.08, velocity) is not None and ball.held == [False]  # let go
    ball.reset_env(0)
    assert ball.seen == [None] and ball.since == [0]


def test_it_waits_for_the_ball_chases_it_and_carries_it_onto_the_target():
    controller = CameraInterceptController(make_task(TASK).template, 0.45, carry=True, paced_every=4,
                                           read_ball=lambda s: s[0], read_target=lambda s: s[1])
    assert controller.spec.harness_inputs and controller.spec.needs_images and controller.stateful
    controller.reset([0])
    prompt = build_prompt(INTERCEPT_INSTRUCTION, [CUE_FACT.format(direction="left", speed=40)],
                          controller.spec.prompt_template)
    target = np.array([0.1, 0.15])
    chunk = controller.act(_obs([-0.2, -0.3, 0.12], 0.08, (None, target)), [prompt])[0]
    assert np.abs(chunk[:, :3]).max() < 0.05 and chunk[0, -1] > 0  # waiting where it comes in, fingers open
    assert np.allclose(controller.targets[0], target)
    chunk = controller.act(_obs([-0.2, -0.3, 0.12], 0.08, (np.array([-0.2, -0.5]), None)), [prompt])[0]
    assert chunk[0, 1] < 0  # toward the ball seen at -y
    ball = controller.ball.where(0, np.zeros(3), 0.08, np.array([0.0, 0.4]))
    at = np.array([*ball[:2], 0.02])
    chunk = controller.act(_obs(at, 0.04, (None, None)), [prompt])[0]  # the fingers closed on it, out of sight
    assert controller.ball.held == [True] and chunk[0, 0] > 0.3 and chunk[0, 1] > 0.3  # carried to the target
    controller.reset_envs([0], [1])
    assert controller.targets == [None] and controller.ball.seen == [None]
    assert isinstance(make_controller("scripted-camera", TASK), CameraInterceptController)
    assert make_controller("scripted-camera", "InterceptGrabSlow-VLA-v0").carry is False


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ["InterceptSlow-VLA-v0", "InterceptGrabMedium-VLA-v0"])
def test_through_the_harness_it_catches_the_ball_as_a_protocol_entry(env_id, tmp_path):
    """Intercept and InterceptGrab at a development seed: the oracle's speed and the writer's (written) each catch
    the ball to success, reading only the harness's observation."""
    results, cells = camera_expert_cells(env_id, tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells
