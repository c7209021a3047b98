"""TraceShape's and TraceShapeSeq's tracing experts on the harness's inputs alone (``scripted-camera``): the green cube
and the button's cap read from the base camera, the cube carried, read again where it fell, and an episode through
MIKASA's harness as a protocol entry."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, camera_expert_cells, harness_obs as _obs

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.trace_shape.camera_expert import (  # noqa: E402
    CUBE_CENTRE_Z, LOOK_POINT, CameraTraceSequenceController, CameraTraceShapeController, read_button_cap,
    read_green_cube)


def test_the_green_cube_and_the_button_cap_are_read_from_the_base_camera():
    env = make_task("TraceShapeSeqEasy-VLA-v0").make_env(obs_mode="rgb")
    try:
        for seed in (5000, 5004):
            obs, _ = env.reset(seed=seed)
            base = env.unwrapped
            rgb = as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0]
            assert np.linalg.norm(read_green_cube(rgb) - as_numpy(base.green_cube.pose.p).reshape(-1)[:2]) < 0.006
            assert np.linalg.norm(read_button_cap(rgb) - as_numpy(base.button_cap.pose.p).reshape(-1)[:2]) < 0.01
    finally:
        env.close()


def test_a_lit_green_is_not_the_cube():
    frame = np.full((128, 128, 3), 120, dtype=np.uint8)
    frame[10:14, 10:14] = (5, 255, 5)  # the lamp, lit
    assert read_green_cube(frame) is None
    frame[60:64, 60:64] = (90, 177, 90)
    assert read_green_cube(frame) is not None


def test_a_cube_that_fell_from_the_fingers_is_looked_for_and_read_again_where_it_lies():
    task = make_task("TraceShapeEasy-VLA-v0")
    controller = CameraTraceShapeController(task.template, paced_every=4, read_cube=lambda seen: seen)
    assert controller.spec.harness_inputs and controller.spec.needs_images and controller.stateful
    controller.reset([0])
    fact = task.cue_fact.format(entity="red cube", shape="circle", cx=-100, cy=0, sx=-100, sy=50)
    prompt = build_prompt(task.instruction_text, [fact], task.template)
    cube = np.array([-0.2, 0.0])
    controller.act(_obs([-0.2, 0.0, CUBE_CENTRE_Z], 0.04, cube), [prompt])  # gripped where it stands
    assert controller.cube.grips[0] is not None and not controller.reads_images()
    controller.act(_obs([-0.1, 0.05, 0.06], 0.04, None), [prompt])  # carried up and off
    chunk = controller.act(_obs([-0.1, 0.05, 0.06], 0.0, None), [prompt])[0]  # it slipped out, the arm hides it
    assert controller.reads_images() and controller.cube.places[0][2] > CUBE_CENTRE_Z
    assert chunk[:, 2].sum() > 2 and LOOK_POINT[2] > 0.2  # up, out of the camera's way
    controller.act(_obs([-0.1, 0.05, 0.25], 0.0, np.array([-0.15, 0.08])), [prompt])  # seen on the table
    assert np.allclose(controller.cube.places[0], [-0.15, 0.08, CUBE_CENTRE_Z])
    controller.reset_envs([0], [1])
    assert controller.cube.places == [None]
    assert isinstance(make_controller("scripted-camera", "TraceShapeHard-VLA-v0"), CameraTraceShapeController)
    assert isinstance(make_controller("scripted-camera", "TraceShapeSeqEasy-VLA-v0"), CameraTraceSequenceController)


def _circle_prompt(task):
    fact = task.cue_fact.format(entity="red cube", shape="circle", cx=-100, cy=0, sx=-100, sy=50)
    return build_prompt(task.instruction_text, [fact], task.template)


def test_a_cube_just_gripped_is_lifted_straight_up_before_the_trace_sets_off_sideways():
    """Setting off sideways once the chunk's prediction had risen jerked the cube out of the fingers a few cm over
    the table: the lift is measured before the pursuit starts."""
    task = make_task("TraceShapeEasy-VLA-v0")
    controller = CameraTraceShapeController(task.template, paced_every=4, read_cube=lambda seen: seen)
    controller.reset([0])
    prompt = _circle_prompt(task)
    lift = controller.act(_obs([-0.2, 0.0, CUBE_CENTRE_Z], 0.04, np.array([-0.2, 0.0])), [prompt])[0]
    assert controller.cube.grips[0] is not None
    assert np.abs(lift[:, :2]).max() < 0.05 and lift[:, 2].max() > 0.3 and (lift[:, 6] < 0).all()  # up, closed
    carried = controller.act(_obs([-0.2, 0.0, controller.trace.carry_z], 0.04, None), [prompt])[0]
    assert np.abs(carried[:, :2]).max() > 0.2 and (carried[:, 6] < 0).all()  # round the path, still closed


def test_fingers_that_closed_on_nothing_lose_the_cube_and_it_is_looked_for_again():
    """A cube jerked out of the fingers drops beside the place it was gripped: the fingers then close there on
    nothing (gap 0), and the hand rises out of the camera's way until the cube is read again."""
    task = make_task("TraceShapeEasy-VLA-v0")
    controller = CameraTraceShapeController(task.template, paced_every=4, read_cube=lambda seen: seen)
    controller.reset([0])
    prompt = _circle_prompt(task)
    controller.act(_obs([-0.2, 0.0, 0.05], 0.08, np.array([-0.2, 0.0])), [prompt])  # seen, the hand over it
    assert not controller.lost[0]
    rise = controller.act(_obs([-0.2, 0.0, CUBE_CENTRE_Z], 0.0, None), [prompt])[0]  # closed on nothing, hidden
    assert controller.lost[0] and controller.reads_images() and rise[:, 2].sum() > 2
    grasp = controller.act(_obs([-0.2, 0.0, 0.25], 0.0, np.array([-0.16, 0.03])), [prompt])[0]
    assert not controller.lost[0] and np.allclose(controller.cube.places[0], [-0.16, 0.03, CUBE_CENTRE_Z])
    assert (grasp[:, 6] > 0).all()  # open, on the way to it
    controller.reset_envs([0], [1])
    assert controller.lost == [False]


@pytest.mark.slow
def test_through_the_harness_it_traces_the_path_as_a_protocol_entry(tmp_path):
    """TraceShapeEasy at a development seed (one of whose cubes slips from the fingers and is grasped again): the
    oracle's path and the writer's (written) each trace it to success, reading only the harness's observation."""
    results, cells = camera_expert_cells("TraceShapeEasy-VLA-v0", tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells
