"""BlinkCountButtonPress's press expert on the harness's inputs alone (``scripted-camera``): the red button and the
phase lamp it reads from the base camera, where it heads for each, and an episode through MIKASA's harness as a
protocol entry."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, camera_expert_cells

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.blink_count.camera_expert import (  # noqa: E402
    CONFIRM_OFFSET, CameraButtonPressController, base_camera_red_cap)
from sb3_memret.tasks.mikasa.blink_count.task import (  # noqa: E402
    CUE_FACT, INSTRUCTION, PROGRESS_PROMPT_TEMPLATE)
from sb3_memret.tasks.mikasa.blink_count.expert import PRESSED_FACT  # noqa: E402

RED = np.array([-0.1, 0.05])  # the red cap's (x, y); the black one stands 16 cm to its +y


def _prompt(count: str | None, presses: str | None = None) -> str:
    facts = ([CUE_FACT.format(count=count)] if count else []) + ([PRESSED_FACT.format(presses=presses)] if presses
                                                                  else [])
    return build_prompt(INSTRUCTION, facts, PROGRESS_PROMPT_TEMPLATE)


def _obs(tcp, seen):
    """The hand's pose as the harness gives it; the "image" is what the stand-in readers see: (cap, green)."""
    return {"extra": {"tcp_pose": np.array([[*tcp, 0, 1, 0, 0]])}, "sensor_data": {"base_camera": {"rgb": [seen]}}}


def _controller():
    return CameraButtonPressController(PROGRESS_PROMPT_TEMPLATE, paced_every=4, read_cap=lambda seen: seen[0],
                                       read_green=lambda seen: seen[1])


def test_it_waits_for_the_button_and_the_green_lamp_then_presses_and_submits_as_its_prompt_says():
    controller = _controller()
    assert controller.spec.harness_inputs and controller.spec.needs_images and controller.stateful
    controller.reset([0])
    over_red = np.array([*RED, 0.015 + 0.043 + 0.13])  # 13 cm over the red cap's top: where it waits
    chunk = controller.act(_obs(over_red, (None, False)), [_prompt("twice")])[0]
    assert np.abs(chunk[:, :3]).max() < 1e-6  # no button in sight: it holds still
    chunk = controller.act(_obs(over_red, (RED, False)), [_prompt("twice")])[0]
    assert abs(chunk[0, 2]) < 0.05  # the cue under way: it stays over the red cap
    chunk = controller.act(_obs(over_red, (None, True)), [_prompt("twice", "once")])[0]  # the cap kept, now green
    assert chunk[0, 2] < -0.5 and not controller.reads_images()  # down to the second press; nothing left to read
    chunk = controller.act(_obs(over_red, (None, True)), [_prompt("twice", "twice")])[0]
    assert chunk[0, 1] > 0.5  # both made: over to the black button, at +y
    controller.reset_envs([0], [1])
    assert controller.caps == [None] and controller.green == [False] and controller.reads_images()


def test_the_black_button_is_where_mikasa_stands_it_and_the_red_cap_is_read_from_the_camera():
    task = make_task("BlinkCountButtonPressEasy-VLA-v0")
    env = task.make_env(obs_mode="rgb")
    try:
        for seed in (5000, 5002):
            obs, _ = env.reset(seed=seed)
            red = as_numpy(env.unwrapped.button_base.pose.p).reshape(-1)
            black = as_numpy(env.unwrapped.confirm_button_base.pose.p).reshape(-1)
            assert np.allclose(black - red, CONFIRM_OFFSET, atol=1e-4)
            cap = base_camera_red_cap(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0])
            assert cap is not None and np.linalg.norm(cap - red[:2]) < 0.005
    finally:
        env.close()


def test_scripted_camera_builds_it_for_every_variant_with_progress():
    from sb3_memret.tasks.mikasa.blink_count.task import BlinkCountTask
    from sb3_memret.tasks.mikasa.camera_experts import camera_expert

    assert isinstance(make_controller("scripted-camera", "BlinkCountButtonPressHard-Long-VLA-v0"),
                      CameraButtonPressController)
    with pytest.raises(ValueError, match="words none"):
        camera_expert(BlinkCountTask("BlinkCountButtonPressEasy-VLA-v0", progress=False))


@pytest.mark.slow
def test_through_the_harness_it_presses_the_count_as_a_protocol_entry(tmp_path):
    """BlinkCountButtonPressEasy at a development seed: the oracle's facts (with MIKASA's press counter) and the
    writers' alone (written) each take it to success, reading only the harness's observation."""
    results, cells = camera_expert_cells("BlinkCountButtonPressEasy-VLA-v0", tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells
