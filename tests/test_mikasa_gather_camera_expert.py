"""GatherAndRecall's gather-and-press expert on the harness's inputs alone (``scripted-camera``): the cubes, the
buttons and the disc read from the base camera's first frame, the cubes carried by the grip, and an episode through
MIKASA's harness as a protocol entry."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, camera_expert_cells, harness_obs as _obs

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.core.carry_expert import CarryGains  # noqa: E402
from sb3_memret.tasks.mikasa.gather_and_recall.camera_expert import (  # noqa: E402
    CameraGatherPressController, HeldCubes, Layout, read_layout)


@pytest.mark.parametrize("env_id", ["GatherAndRecall1-VLA-v0", "GatherAndRecall5-VLA-v0"])
def test_the_cubes_in_mikasas_order_the_buttons_and_the_disc_are_read_from_the_base_camera(env_id):
    task = make_task(env_id)
    env = task.make_env(obs_mode="rgb")
    try:
        for seed in (5000, 5003):
            obs, _ = env.reset(seed=seed)
            layout = read_layout(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0], task.n_cubes, task.words)
            base = env.unwrapped
            cubes = np.array([as_numpy(cube.pose.p).reshape(-1) for cube in base.cubes])
            buttons = np.array([as_numpy(button.pose.p).reshape(-1) for button in base.button_bases])
            assert np.linalg.norm(layout.cubes[:, :2] - cubes[:, :2], axis=1).max() < 0.008
            assert np.linalg.norm(layout.buttons[:, :2] - buttons[:, :2], axis=1).max() < 0.008
            assert np.linalg.norm(layout.disc[:2] - as_numpy(base.disc.pose.p).reshape(-1)[:2]) < 0.008
        assert read_layout(np.zeros((128, 128, 3), np.uint8), task.n_cubes, task.words) is None
    finally:
        env.close()


def test_the_cube_the_fingers_close_on_is_carried_and_left_where_let_go():
    cubes = HeldCubes(CarryGains(), np.array([[0.0, -0.3, 0.02], [0.1, -0.3, 0.02]]))
    assert cubes.held is None
    cubes.track(np.array([0.1, -0.3, 0.02]), 0.04)  # closed on the second
    assert cubes.held == 1
    assert np.allclose(cubes.track(np.array([0.1, 0.1, 0.06]), 0.04)[1], [0.1, 0.1, 0.06])
    cubes.track(np.array([0.1, 0.1, 0.026]), 0.04)
    places = cubes.track(np.array([0.1, 0.1, 0.026]), 0.08)  # let go, resting on the disc
    assert cubes.held is None and np.allclose(places, [[0.0, -0.3, 0.02], [0.1, 0.1, 0.026]])


def test_it_gathers_from_what_it_read_and_presses_its_prompts_colour():
    task = make_task("GatherAndRecall1-VLA-v0")
    layout = Layout(np.array([[-0.1, -0.26, 0.02]]),
                    np.array([[-0.2, -0.02, 0.015], [-0.2, 0.12, 0.015], [-0.2, 0.26, 0.015]]),
                    np.array([0.02, 0.12, 0.003]))
    controller = CameraGatherPressController(task.template, task.words, task.words[0], n_cubes=1, paced_every=4,
                                             read=lambda seen: seen)
    assert controller.spec.harness_inputs and controller.spec.needs_images and controller.stateful
    controller.reset([0])
    prompt = build_prompt(task.instruction_text, [task.cue_fact.format(colour="blue")], task.template)

    assert np.all(controller.act(_obs([0.0, 0.0, 0.3], 0.08, None), [prompt]) == 0)  # nothing read yet: still
    chunk = controller.act(_obs([0.0, 0.0, 0.3], 0.08, layout), [prompt])[0]
    assert chunk[0, 1] < -0.5 and not controller.reads_images()  # to the cube, at -y
    controller.act(_obs([-0.1, -0.26, 0.02], 0.04, None), [prompt])  # gripped
    controller.act(_obs([0.02, 0.12, 0.026], 0.04, None), [prompt])  # carried onto the disc
    controller.act(_obs([0.02, 0.12, 0.026], 0.08, None), [prompt])  # let go there
    chunk = controller.act(_obs([0.02, 0.12, 0.15], 0.08, None), [prompt])[0]
    assert chunk[0, 0] < -0.5 and chunk[0, 1] > 0.5  # to the blue button, nearer the robot and to its left
    controller.reset_envs([0], [1])
    assert controller.layouts == [None] and controller.reads_images()
    assert isinstance(make_controller("scripted-camera", "GatherAndRecall9-VLA-v0"), CameraGatherPressController)


@pytest.mark.slow
def test_through_the_harness_it_gathers_and_presses_as_a_protocol_entry(tmp_path):
    """GatherAndRecall3 at a development seed: the oracle's colour and the writer's (written) each lead to success,
    reading only the harness's observation."""
    results, cells = camera_expert_cells("GatherAndRecall3-VLA-v0", tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells
