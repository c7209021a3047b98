"""TakeItBack's carry-back expert on the harness's inputs alone (``scripted-camera``): the cube, the red target and
its turn to purple read from the base camera, and an episode through MIKASA's harness as a protocol entry."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, camera_expert_cells, harness_obs as _obs

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.take_it_back.camera_expert import (  # noqa: E402
    CUBE_CENTRE_Z, CameraCarryBackController, purple_target_seen, read_cube_top, read_red_target)
from sb3_memret.tasks.mikasa.take_it_back.task import (  # noqa: E402
    CUE_FACT, DEFAULT_SIDE, INSTRUCTION, PROMPT_TEMPLATE, SIDE_CENTRES)

TASK = "TakeItBack-VLA-v0"


def test_the_cube_the_target_and_its_turn_are_read_from_the_base_camera():
    from mani_skill.utils.structs.pose import Pose

    env = make_task(TASK).make_env(obs_mode="rgb")
    try:
        for seed in (5000, 5007):  # 5007: the farthest cube reading of ten development seeds
            obs, _ = env.reset(seed=seed)
            base = env.unwrapped
            rgb = as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0]
            cube, goal = (as_numpy(actor.pose.p).reshape(-1) for actor in (base.cube, base.goal_region))
            assert np.linalg.norm(read_cube_top(rgb) - cube[:2]) < 0.006
            assert np.linalg.norm(read_red_target(rgb) - goal[:2]) < 0.015 and not purple_target_seen(rgb)
        red, purple = base.goal_region, base.changed_goal_region  # turn it as MIKASA does: purple in, red out
        place, hidden = red.pose.p.clone(), red.pose.p.clone()
        hidden[..., 2] = 1000.0
        purple.set_pose(Pose.create_from_pq(place, red.pose.q))
        red.set_pose(Pose.create_from_pq(hidden, red.pose.q))
        rgb = as_numpy(base.get_obs()["sensor_data"]["base_camera"]["rgb"])[0]
        assert purple_target_seen(rgb) and read_red_target(rgb) is None
    finally:
        env.close()


def test_it_takes_the_cube_to_the_target_then_back_to_the_start_its_prompt_names():
    controller = CameraCarryBackController(SIDE_CENTRES, DEFAULT_SIDE, PROMPT_TEMPLATE, paced_every=4,
                                           read_cube=lambda s: s[0], read_target=lambda s: s[1],
                                           turned=lambda s: s[2])
    assert controller.spec.harness_inputs and controller.spec.needs_images and controller.stateful
    controller.reset([0])
    prompt = build_prompt(INSTRUCTION, [CUE_FACT.format(side="left")], PROMPT_TEMPLATE)
    cube, target = np.array([0.0, 0.1]), np.array([0.2, 0.0])
    at_cube = np.array([*cube, CUBE_CENTRE_Z])
    controller.act(_obs(at_cube, 0.04, (cube, target, False)), [prompt])  # gripped where it was seen
    chunk = controller.act(_obs(at_cube + [0, 0, 0.04], 0.04, (None, None, False)), [prompt])[0]
    assert chunk[0, 0] > 0.5 and controller.reads_images()  # carrying it to the target, at +x
    over_target = np.array([*target, 0.06])
    chunk = controller.act(_obs(over_target, 0.04, (None, None, True)), [prompt])[0]  # the target turned
    assert chunk[0, 1] > 0.5 and not controller.reads_images()  # back to the left start, at +y
    controller.reset_envs([0], [1])
    assert controller.cube.places == [None] and controller.returning == [False]
    assert isinstance(make_controller("scripted-camera", TASK), CameraCarryBackController)


@pytest.mark.slow
def test_through_the_harness_it_takes_the_cube_back_as_a_protocol_entry(tmp_path):
    """TakeItBack at a development seed: the oracle's start and the writer's (written) each take it to success,
    reading only the harness's observation."""
    results, cells = camera_expert_cells(TASK, tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells
