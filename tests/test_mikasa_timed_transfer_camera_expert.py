"""TimedTransfer's timed carry expert on the harness's inputs alone (``scripted-camera``): the cube it reads from the
base camera, the grip it tracks from the gripper's opening, and an episode through MIKASA's harness as a protocol
entry."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, camera_expert_cells, harness_obs as _obs

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.timed_transfer.camera_expert import (  # noqa: E402
    CUBE_CENTRE_Z, RED_DISC_OFFSET, CameraTimedTransferController, base_camera_blue_cube)

TASK = "TimedTransferEasy-VLA-v0"
CUBE = np.array([-0.1, -0.1])  # where the stand-in reader sees the cube


def _prompt(task, count: int | None) -> str:
    facts = [] if count is None else [f"the lamp turned green {count} steps ago."]
    return build_prompt(task.instruction_text.format(delay=100), facts, task.template)


def test_it_grips_the_cube_it_saw_carries_it_at_its_grip_and_sets_it_down_when_due():
    task = make_task(TASK)
    controller = CameraTimedTransferController(task.template, paced_every=task.replan_every, read_cube=lambda s: s)
    assert controller.spec.harness_inputs and controller.spec.needs_images and controller.stateful
    controller.reset([0])
    high = np.array([-0.1, 0.0, 0.2])
    chunk = controller.act(_obs(high, 0.08, None), [_prompt(task, None)])[0]
    assert np.abs(chunk[:, :3]).max() < 1e-6 and controller.reads_images()  # no cube in sight: it holds still
    chunk = controller.act(_obs(high, 0.08, CUBE), [_prompt(task, 10)])[0]
    assert chunk[0, 1] < -0.5 and not controller.reads_images()  # to the cube, at y = -0.1; nothing left to read
    at_cube = np.array([*CUBE, CUBE_CENTRE_Z])
    controller.act(_obs(at_cube, 0.04, None), [_prompt(task, 10)])  # the fingers closed on it: gripped
    lifted = at_cube + [0.0, 0.05, 0.06]
    controller.act(_obs(lifted, 0.04, None), [_prompt(task, 20)])
    assert np.allclose(controller.cube.places[0], lifted)  # carried at the grip's offset
    over_red = np.array([*(CUBE + RED_DISC_OFFSET[:2]), 0.09])
    hold = controller.act(_obs(over_red, 0.04, None), [_prompt(task, 50)])[0]
    down = controller.act(_obs(over_red, 0.04, None), [_prompt(task, 98)])[0]
    assert abs(hold[0, 2]) < 0.05 and down[0, 2] < -0.3  # held over the red disc until the count is due
    controller.act(_obs(over_red, 0.0, None), [_prompt(task, 99)])  # let go (the fingers shut on nothing)
    assert controller.cube.grips[0] is None and np.allclose(controller.cube.places[0], over_red)
    controller.reset_envs([0], [1])
    assert controller.starts == [None] and controller.reads_images()


def test_the_cube_is_read_from_the_base_camera_within_a_centimetre():
    task = make_task(TASK)
    env = task.make_env(obs_mode="rgb")
    try:
        for seed in (5000, 5005):  # 5005: the farthest of ten development seeds
            obs, _ = env.reset(seed=seed)
            cube = as_numpy(env.unwrapped.blue_cube.pose.p).reshape(-1)
            seen = base_camera_blue_cube(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0])
            assert seen is not None and np.linalg.norm(seen - cube[:2]) < 0.01
            red = as_numpy(env.unwrapped.red_disc.pose.p).reshape(-1)
            assert np.allclose(red[:2] - cube[:2], RED_DISC_OFFSET[:2], atol=1e-4)  # the cube rests on the green disc
    finally:
        env.close()
    built = make_controller("scripted-camera", "TimedTransferHard-Long-VLA-v0")
    assert isinstance(built, CameraTimedTransferController)


@pytest.mark.slow
def test_through_the_harness_it_sets_the_cube_down_on_time_as_a_protocol_entry(tmp_path):
    """TimedTransferEasy at a development seed: the oracle's count and the writer's (written) each take it to
    success, reading only the harness's observation."""
    results, cells = camera_expert_cells(TASK, tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells
