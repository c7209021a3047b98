"""BatteriesChecker's check-cycle expert on the harness's inputs alone (``scripted-camera``): the tray, socket and
button read and laid from the base camera's first frame, a battery carried by the grip and found again once let go,
and an episode through MIKASA's harness as a protocol entry."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, camera_expert_cells, harness_obs as _obs

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.batteries_checker.camera_expert import (  # noqa: E402
    BatteryLayout, CameraBatteryCheckController, CameraCheckGains, SeenBatteries, read_tray)
from sb3_memret.tasks.mikasa.batteries_checker.checklist import checklist_fact  # noqa: E402

SLOTS = np.array([[-0.05, -0.1, 0.03], [-0.10, -0.1, 0.03], [-0.15, -0.1, 0.03]])
SOCKET, CAP = np.array([0.15, -0.1, 0.03]), np.array([-0.05, 0.14, 0.058])


@pytest.mark.parametrize("env_id", ["BatteriesCheckerEasy-3-VLA-v0", "BatteriesCheckerHard-6-VLA-v0"])
def test_the_slots_socket_and_button_are_read_and_laid_from_the_base_camera(env_id):
    task = make_task(env_id)
    env = task.make_env(obs_mode="rgb")
    n = task.variant.batteries
    try:
        for seed in (5000, 5004, 5014):  # at 5014 (Easy-3) two tops touch in the picture
            obs, _ = env.reset(seed=seed)
            layout = read_tray(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0], n)
            base = env.unwrapped
            slots = as_numpy(base.tray_slot_positions)[0, :n]
            batteries = np.array([as_numpy(b.pose.p).reshape(-1) for b in base.batteries[:n]])
            assert np.linalg.norm(layout.slots - slots, axis=1).max() < 0.008
            assert np.linalg.norm(layout.slots - batteries, axis=1).max() < 0.008  # where each stands at home
            assert np.linalg.norm(layout.socket - as_numpy(base.socket_slot_pos)[0]) < 0.006
            assert np.linalg.norm(layout.cap[:2] - as_numpy(base.button_xy)[0]) < 0.008
            assert layout.cap[2] == pytest.approx(float(as_numpy(base.button_top_z)[0]))
        assert read_tray(np.zeros((128, 128, 3), np.uint8), n) is None
    finally:
        env.close()


def test_a_battery_let_go_is_unsettled_until_two_readings_agree_and_others_explain_their_own_tops():
    readings = []
    seen = SeenBatteries(CameraCheckGains(), SLOTS, SOCKET, lambda rgb: readings.pop(0))
    seen.track(SLOTS[1] + [0, 0, 0.005], 0.016, None)  # closed on the second
    assert seen.held == 1
    carried = seen.track(SOCKET + [0, 0, 0.045], 0.016, None)[1]
    assert np.allclose(carried, SOCKET + [0, 0, 0.04])
    readings += [SLOTS[:, :2]]  # let go: every top explained but its own, now home again (Easy's snap)
    seen.track(SOCKET + [0, 0, 0.045], 0.03, None)
    assert seen.held is None and seen.unsettled == 1
    readings += [SLOTS[:, :2] + [0.001, 0]]
    assert np.allclose(seen.track(SOCKET + [0, 0, 0.1], 0.03, None)[1], SLOTS[1])  # read near its slot: there
    assert seen.unsettled is None and not readings
    seen.track(SLOTS[1] + [0, 0, 0.005], 0.016, None)  # taken again, let go by the socket: read in it, then beside it
    seen.track(SOCKET + [0, 0, 0.02], 0.016, None)
    readings += [np.array([SOCKET[:2] + [0.02, 0]])] * 2 + [np.array([SOCKET[:2] + [0.05, 0]])] * 4
    seen.track(SOCKET + [0, 0, 0.02], 0.03, None)
    assert np.allclose(seen.track(SOCKET + [0, 0, 0.02], 0.03, None)[1], SOCKET + [0, 0, 0.011])  # seated
    seen.track(SOCKET + [0, 0, 0.005], 0.016, None)
    seen.track(SOCKET + [0, 0, 0.005], 0.03, None)
    seen.track(SOCKET + [0, 0, 0.005], 0.03, None)  # a top away from every seat, read from low down: not taken
    assert seen.unsettled == 1 and seen.reading is None
    seen.track(SOCKET + [0, 0, 0.3], 0.03, None)  # read from the look height: taken
    assert np.allclose(seen.track(SOCKET + [0, 0, 0.3], 0.03, None)[1], [*(SOCKET[:2] + [0.05, 0]), 0.03])
    assert not readings

    lost = SeenBatteries(CameraCheckGains(unseen_calls=2), SLOTS, SOCKET, lambda rgb: SLOTS[[1, 2], :2])
    lost.track(SLOTS[0] + [0, 0, 0.005], 0.016, None)
    lost.track(SLOTS[0] + [0.05, 0, 0.1], 0.016, None)
    lost.track(SLOTS[0] + [0.05, 0, 0.1], 0.03, None)  # let go; every top in sight is another battery's
    assert lost.unsettled == 0
    places = lost.track(SLOTS[0] + [0.05, 0, 0.15], 0.03, None)
    assert lost.unsettled is None and np.allclose(places[0], SLOTS[0] + [0.05, 0, 0.095])  # unseen: where let go


def test_it_checks_the_first_battery_its_checklist_leaves_out_and_rises_out_of_view_after_letting_go():
    task = make_task("BatteriesCheckerEasy-3-VLA-v0")
    tops = [SLOTS[:, :2]]
    controller = CameraBatteryCheckController(task.template, hard=False, n_batteries=3, paced_every=4,
                                              read=lambda seen: seen, tops=lambda rgb: tops[-1])
    assert controller.spec.harness_inputs and controller.spec.needs_images and controller.stateful
    controller.reset([0])
    prompt = build_prompt(task.instruction_text, [checklist_fact({1: True})], task.template)
    assert np.all(controller.act(_obs([0.0, 0.0, 0.3], 0.03, None), [prompt])[0, :, :6] == 0)  # nothing read yet
    chunk = controller.act(_obs([0.0, 0.0, 0.3], 0.03, BatteryLayout(SLOTS, SOCKET, CAP, np.array([-0.1, -0.1]))), [prompt])[0]
    assert controller.cycles[0].battery == 1 and chunk[0, 0] < -0.5 and chunk[0, 1] < -0.5  # to slot 2
    controller.act(_obs(SLOTS[1] + [0, 0, 0.005], 0.016, None), [prompt])
    assert controller.cycles[0].stage == "insert"
    controller.act(_obs(SOCKET + [0, 0, 0.045], 0.016, None), [prompt])
    tops[-1] = SLOTS[[0, 2], :2]  # the arm hides it
    chunk = controller.act(_obs(SOCKET + [0, 0, 0.045], 0.03, None), [prompt])[0]  # let go over the socket
    assert controller.batteries[0].unsettled == 1 and np.abs(chunk[0, :3]).max() < 0.1  # still, looking for it
    chunk = controller.act(_obs(SOCKET + [0, 0, 0.045], 0.03, None), [prompt])[0]
    far = controller.check.far_action  # the socket beyond far_x: short actions
    assert chunk[0, 2] > 0.8 * far and abs(chunk[0, 0]) < 0.05  # unseen twice: up, to look from over the tray
    tops[-1] = SLOTS[:, :2]
    controller.act(_obs(SOCKET + [0, 0, 0.2], 0.03, None), [prompt])
    chunk = controller.act(_obs(SOCKET + [0, 0, 0.2], 0.03, None), [prompt])[0]  # seen home twice: settled
    assert controller.batteries[0].unsettled is None
    chunk = controller.act(_obs(SOCKET + [0, 0, 0.2], 0.03, None), [prompt])[0]
    assert controller.cycles[0].stage == "press" and chunk[0, 0] < -far / 3 and chunk[0, 1] > far / 3  # to the button
    controller.reset_envs([0], [1])
    assert controller.layouts == [None] and controller.batteries == [None]
    assert isinstance(make_controller("scripted-camera", "BatteriesCheckerHard-6-VLA-v0"),
                      CameraBatteryCheckController)


@pytest.mark.slow
def test_through_the_harness_it_checks_every_battery_as_a_protocol_entry(tmp_path):
    """BatteriesCheckerEasy-3 at a development seed: the oracle's checklist (MIKASA's counters) and the writer's
    (written) each lead to success, reading only the harness's observation."""
    results, cells = camera_expert_cells("BatteriesCheckerEasy-3-VLA-v0", tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells
