"""Rotate's peg-turning expert on the harness's inputs alone (``scripted-camera``): the peg read from the base camera
(whole, or the strip the hand leaves in sight), the peg in hand, the wrist dead-reckoned, and an episode through
MIKASA's harness as a protocol entry."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mikasa_support import MIKASA_MISSING, camera_expert_cells, harness_obs as _obs

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC  # noqa: E402
from sb3_memret.tasks.mikasa.rotate.camera_expert import (  # noqa: E402
    HIDDEN_SLIDE, HIDDEN_TURN_PER_METRE, REST_WRIST, CameraPegTurnController, PegInHand, PegSighting, WristEstimate,
    pushed_peg, read_peg, side_of)
from sb3_memret.tasks.mikasa.rotate.expert import PEG_HALF_WIDTH, TurnGains, wrap  # noqa: E402
from sb3_memret.tasks.mikasa.rotate.task import (  # noqa: E402
    CUE_FACT, LENIENT_INSTRUCTION, peg_on_table, peg_top_mask, peg_yaw)

TASK = "RotateLenientPos-VLA-v0"


def test_the_peg_is_read_whole_from_the_base_camera():
    env = make_task(TASK).make_env(obs_mode="rgb")
    try:
        errors = []
        for seed in range(5000, 5005):
            obs, _ = env.reset(seed=seed)
            seen = read_peg(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0])
            peg = env.unwrapped.peg
            yaw = float(as_numpy(peg_yaw(peg.pose.q)).reshape(-1)[0])
            errors.append(abs(float(wrap(seen.yaw - yaw))))
            assert errors[-1] < np.radians(2)  # the rectangle's sides lie along the pixel grid's steps
            assert np.linalg.norm(seen.centre - as_numpy(peg.pose.p).reshape(-1)[:2]) < 0.02
            assert 0.23 < seen.length < 0.24  # the 24 cm face, to the pixel centres at its ends
        assert np.mean(errors) < np.radians(1)
    finally:
        env.close()


def test_a_finger_over_one_side_of_the_face_leaves_its_axis():
    """Pushing, the fingers hide one long side of the face near an end: the smallest rectangle round what is left
    keeps the other side's line, where the pixels' principal axis (the writer's first-sight reader) tilts."""
    env = make_task(TASK).make_env(obs_mode="rgb")
    try:
        rect_errors = []
        for seed in range(5000, 5006):
            obs, _ = env.reset(seed=seed)
            rgb = np.array(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0])
            yaw = float(as_numpy(peg_yaw(env.unwrapped.peg.pose.q)).reshape(-1)[0])
            rows, cols = np.nonzero(peg_top_mask(rgb))
            pixels = np.stack([rows, cols], axis=1).astype(float)
            pixels -= pixels.mean(axis=0)
            _, vectors = np.linalg.eigh(np.cov(pixels.T))
            along, across = pixels @ vectors[:, -1], pixels @ vectors[:, 0]
            hidden = (along > np.percentile(along, 55)) & (across > 0)
            rgb[rows[hidden], cols[hidden]] = (60, 60, 60)  # a grey finger over one side of one end
            rect_error = abs(float(wrap(read_peg(rgb).yaw - yaw)))
            principal = np.radians(peg_on_table(rgb, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC)[1])
            assert rect_error < np.radians(2.5) and rect_error < abs(float(wrap(principal - yaw)))
            rect_errors.append(rect_error)
        assert np.mean(rect_errors) < np.radians(1.5)
    finally:
        env.close()


def _tcp(x, y, yaw, z=0.1):
    """A TCP pose (x, y, z, qw, qx, qy, qz) pointing down, the hand turned ``yaw`` about the vertical."""
    q = (Rotation.from_rotvec([0, 0, yaw]) * Rotation.from_euler("x", np.pi)).as_quat()
    return np.array([x, y, z, q[3], q[0], q[1], q[2]])


def test_the_wrist_turns_against_the_hand_and_with_the_arm():
    wrist = WristEstimate()
    wrist.reset(1)
    assert wrist.angle(0, _tcp(0.0, 0.0, 0.3)) == pytest.approx(REST_WRIST)
    assert wrist.angle(0, _tcp(0.0, 0.0, 0.8)) == pytest.approx(REST_WRIST - 0.5)  # the hand turned, not the arm
    turned_arm = np.arctan2(0.2, 0.615)
    assert wrist.angle(0, _tcp(0.0, 0.2, 0.8 + turned_arm)) == pytest.approx(REST_WRIST - 0.5)  # both turned
    for yaw in (2.0, 3.0, 4.0):  # past +-180 degrees the hand's yaw keeps counting
        angle = wrist.angle(0, _tcp(0.0, 0.2, yaw + turned_arm))
    assert angle == pytest.approx(REST_WRIST - 3.7)
    wrist.reset_env(0)
    assert wrist.angle(0, _tcp(0.1, 0.0, -1.0)) == pytest.approx(REST_WRIST)


def test_a_gripped_peg_turns_with_the_hand_until_let_go_and_a_fresh_reading_refixes_it():
    hand = PegInHand()
    hand.reset(1)
    assert hand.track(0, True, False, 0.2, 1.0, fresh=True) is None  # gripped, but not at the peg last seen
    assert hand.track(0, True, True, 0.2, 1.0, fresh=True) == pytest.approx(1.0)
    assert hand.track(0, True, False, 0.7, 1.0, fresh=False) == pytest.approx(1.5)  # carried off unseen: turned
    assert hand.track(0, True, False, 0.7, 1.45, fresh=True) == pytest.approx(1.45)  # seen: the reading stands ...
    assert hand.track(0, True, False, 0.8, 1.45, fresh=False) == pytest.approx(1.55)  # ... and is the new fix
    assert hand.track(0, False, True, 0.7, 1.0, fresh=True) is None and hand.offsets == [None]


def _sighting(centre, yaw, pixels, half_length):
    axis = np.array([np.cos(yaw), np.sin(yaw)])
    centre = np.asarray(centre, dtype=float)
    return PegSighting(centre, yaw, pixels, np.stack([centre - half_length * axis, centre + half_length * axis]))


def test_a_strip_of_the_face_gives_the_axis_and_the_far_end_both_ends_the_centre_a_thin_strip_nothing():
    controller = CameraPegTurnController(make_task(TASK).template, "push", 0, paced_every=4, read=lambda s: s)
    assert controller.spec.harness_inputs and controller.spec.needs_images and controller.stateful
    controller.reset([0])
    prompt = build_prompt(LENIENT_INSTRUCTION.format(angle_deg=40), [CUE_FACT.format(start_deg=0)],
                          controller.spec.prompt_template)
    assert np.all(controller.act(_obs(_tcp(0.3, 0.0, 0.0), 0.0, None), [prompt])[0, :, :6] == 0)  # no peg yet: still
    controller.act(_obs(_tcp(0.3, 0.0, 0.0), 0.0, _sighting([0.0, 0.0], 0.0, 100, 0.118)), [prompt])
    # the hand over the +x end, the peg turned 0.2 rad about its -x end: the strip from that end, full width
    far = np.array([-0.118, 0.0])
    axis = np.array([np.cos(0.2), np.sin(0.2)])
    strip = PegSighting(far + 0.06 * axis, 0.2, 50, np.stack([far, far + 0.12 * axis]))
    controller.act(_obs(_tcp(0.1, 0.02, 0.0, z=0.02), 0.0, strip), [prompt])
    peg = controller.pegs[0]
    assert peg.yaw == pytest.approx(0.2) and np.allclose(peg.centre, far + 0.118 * axis)
    controller.act(_obs(_tcp(0.1, 0.02, 0.0, z=0.2), 0.0, PegSighting(far + 0.06 * axis, 0.5, 50, strip.ends)),
                   [prompt])  # the same strip with the hand high up: the arm may hide any part, no far end
    assert controller.pegs[0] is peg
    thin = PegSighting(far + 0.06 * axis, 0.6, 20, np.stack([far, far + 0.12 * axis]))
    controller.act(_obs(_tcp(0.1, 0.02, 0.0, z=0.06), 0.0, thin), [prompt])  # (the hand up: pushing nothing)
    assert controller.pegs[0] is peg
    ends = np.stack([far, far + 0.236 * axis])  # both ends in sight, the fingers over the middle
    controller.act(_obs(_tcp(0.0, 0.0, 0.0, z=0.05), 0.0, PegSighting(ends.mean(axis=0) + 0.01, 0.2, 60, ends)), [prompt])
    assert np.allclose(controller.pegs[0].centre, ends.mean(axis=0))
    controller.reset_envs([0], [1])
    assert controller.pegs == [None] and controller.wholes == [None]
    assert isinstance(make_controller("scripted-camera", TASK), CameraPegTurnController)
    assert make_controller("scripted-camera", "RotateStrictPos-VLA-v0").strategy == "grasp"


def test_fingers_that_would_stand_inside_a_peg_read_before_have_pushed_it_on():
    """The arm hides the peg it pushes: the last reading is pushed on by the depth the closed fingers would stand
    inside it, from the side they came from, turned the way the lever arm says and slid by the measured share."""
    gains = TurnGains()
    peg = PegSighting(np.zeros(2), 0.0, 100, np.array([[-0.118, 0.0], [0.118, 0.0]]))
    depth = PEG_HALF_WIDTH + gains.finger - 0.02
    ccw = pushed_peg(peg, np.array([0.1, -0.02]), gains)  # the +x end pushed towards +y
    assert ccw.yaw == pytest.approx(HIDDEN_TURN_PER_METRE * depth)
    assert ccw.centre == pytest.approx([0.0, HIDDEN_SLIDE * depth])
    cw = pushed_peg(peg, np.array([-0.1, -0.02]), gains)  # the -x end pushed towards +y
    assert wrap(cw.yaw) == pytest.approx(-HIDDEN_TURN_PER_METRE * depth)
    assert pushed_peg(peg, np.array([0.1, -0.05]), gains) is peg  # behind its face, not touching
    assert pushed_peg(peg, np.array([0.15, -0.01]), gains) is peg  # beyond its end
    # fingers from -y that passed the axis read last (the peg went on ahead of them) push it on, not back
    crossed = pushed_peg(peg, np.array([0.1, 0.01]), gains, side=-1.0)
    assert crossed.yaw == pytest.approx(HIDDEN_TURN_PER_METRE * (PEG_HALF_WIDTH + gains.finger + 0.01))
    assert wrap(pushed_peg(peg, np.array([0.1, 0.01]), gains).yaw) < 0  # (read from where they stand: backwards)
    assert side_of(peg, np.array([0.1, -0.05]), gains) == -1.0 and side_of(peg, np.array([0.1, 0.01]), gains) is None

    controller = CameraPegTurnController(make_task(TASK).template, "push", 0, paced_every=4, read=lambda s: s)
    controller.reset([0])
    prompt = build_prompt(LENIENT_INSTRUCTION.format(angle_deg=40), [CUE_FACT.format(start_deg=0)],
                          controller.spec.prompt_template)
    controller.act(_obs(_tcp(0.3, 0.0, 0.0), 0.0, peg), [prompt])
    controller.act(_obs(_tcp(0.1, -0.02, 0.0, z=0.08), 0.0, None), [prompt])  # hidden, the hand over it
    assert controller.pegs[0] is peg
    controller.act(_obs(_tcp(0.1, -0.02, 0.0, z=0.02), 0.0, None), [prompt])  # hidden, the fingers down in it
    assert controller.pegs[0].yaw == pytest.approx(ccw.yaw) and controller.sides == [-1.0]
    controller.act(_obs(_tcp(0.1, 0.03, 0.0, z=0.02), 0.0, None), [prompt])  # on past the axis first read
    assert controller.pegs[0].yaw > ccw.yaw and controller.sides == [-1.0]  # pushed on the same way


@pytest.mark.slow
@pytest.mark.parametrize("env_id", [TASK, "RotateStrictPos-VLA-v0"])
def test_through_the_harness_it_turns_the_peg_as_a_protocol_entry(env_id, tmp_path):
    """Rotate at a development seed, pushed (Lenient) and turned in hand (Strict): the oracle's start and the
    writer's (written) each turn the peg to success, reading only the harness's observation."""
    results, cells = camera_expert_cells(env_id, tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells
