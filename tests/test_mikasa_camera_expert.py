"""The colour-cue expert on the harness's inputs alone (``scripted-camera``): the layout it tracks from the base
camera, its motion from the hand's pose, the pace it refuses to be run at otherwise, and an episode through MIKASA's
harness under the simulator guard."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.pacing import replan_interval  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.core.layout_perception import LAYOUT_PLANE_Z, CubeLayout  # noqa: E402
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES  # noqa: E402
from sb3_memret.tasks.mikasa.seq_of_colors.camera_expert import CameraSequenceController  # noqa: E402
from sb3_memret.tasks.mikasa.seq_of_colors.task import (  # noqa: E402
    INSTRUCTION, PROGRESS_PROMPT_TEMPLATE, sequence_facts)
from sb3_memret.tasks.mikasa.seq_of_colors.writer import BUTTON_BASE_Z, BUTTON_TOWARD_ROBOT  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402

ARC = {c: np.array([0.05, y]) for c, y in zip(COLOUR_NAMES, np.linspace(-0.3, 0.3, 9))}  # red at y = -0.3


class CountingReader:
    """A stand-in image reader: the "image" is the layout it shows; counts the frames it was asked to read."""

    def __init__(self):
        self.calls = 0

    def __call__(self, seen):
        self.calls += 1
        return seen


def test_the_layout_places_each_colour_at_its_first_sighting_once_the_cubes_are_out_and_then_reads_no_more():
    reader = CountingReader()
    layout = CubeLayout(shown_at_once=3, read=reader)
    layout.see({"red": np.zeros(2), "lime": np.ones(2), "blue": np.ones(2)})  # a bunch of three: the cue
    assert layout.places == {} and not layout.complete
    first = {c: p for c, p in ARC.items() if c != "teal"}  # the arm hides teal
    layout.see(first)
    assert sorted(layout.places) == sorted(first) and not layout.complete
    layout.see({**ARC, "red": np.array([9.0, 9.0])})  # teal seen now; red, already placed, is not moved
    assert layout.complete and np.allclose(layout.places["red"], ARC["red"])
    calls = reader.calls
    layout.see(ARC)
    assert reader.calls == calls  # complete: the image is not read again
    layout.reset()
    assert layout.places == {}
    with pytest.raises(ValueError, match="shown_at_once"):
        CubeLayout(shown_at_once=9)


def _obs(tcp, seen, batch=1):
    return {"extra": {"tcp_pose": np.tile([*tcp, 0, 1, 0, 0], (batch, 1))},
            "sensor_data": {"base_camera": {"rgb": [seen] * batch}}}


def _controller(paced_every=4):
    return CameraSequenceController(PROGRESS_PROMPT_TEMPLATE, shown_at_once=1, paced_every=paced_every,
                                    read_layout=lambda seen: seen)


def test_it_waits_until_the_camera_has_placed_every_cube_then_heads_for_the_first_colour_and_the_button():
    controller = _controller()
    assert controller.spec.harness_inputs and controller.spec.needs_images and controller.stateful
    controller.reset([0])
    prompt = build_prompt(INSTRUCTION, sequence_facts(("red", "teal", "lime")), PROGRESS_PROMPT_TEMPLATE)
    ready = np.asarray(controller.gains.ready)
    chunk = controller.act(_obs(ready, {"red": np.zeros(2)}), [prompt])[0]  # the cue at the table centre
    assert np.abs(chunk[:, :3]).max() < 1e-6  # at its ready pose, it waits there
    chunk = controller.act(_obs(ready, ARC), [prompt])[0]
    assert chunk[0, 1] < 0  # towards red, at y = -0.3
    cubes, visible, button = controller._detections(_obs(ready, {}))  # placed: nothing more is read
    assert visible.all() and np.allclose(cubes[0, 0], [*ARC["red"], LAYOUT_PLANE_Z])
    mean = np.mean(list(ARC.values()), axis=0)
    assert np.allclose(button[0], [mean[0] - BUTTON_TOWARD_ROBOT, mean[1], BUTTON_BASE_Z])
    done = build_prompt(INSTRUCTION, [*sequence_facts(("red",)), "the red cube was touched."],
                        PROGRESS_PROMPT_TEMPLATE)
    chunk = controller.act(_obs(ready, ARC), [done])[0]
    assert chunk[0, 0] > 0.5 and abs(chunk[0, 1]) < 0.25 * chunk[0, 0]  # red done: to the button, 9 cm ahead (+x)
    controller.reset_envs([0], [1])
    assert controller.layouts[0].places == {} and controller.hand.sent[0] is None


def test_its_motion_is_dead_reckoned_from_the_actions_that_ran_and_corrected_by_the_hand_and_it_refuses_another_pace():
    from sb3_memret.tasks.mikasa.core.touch_expert import COAST_GAIN, DRIVE_GAIN, POS_SCALE

    controller = _controller(paced_every=4)
    controller.reset([0])
    here = np.array([0.0, 0.0, 0.2])
    hand = controller.hand
    assert np.allclose(hand.step_now(0, here), 0)  # an episode's first call: no motion known
    full = np.tile([1.0, 0.0, 0.0], (4, 1))  # four full actions along x, from rest
    steps = []
    for _ in range(4):
        steps.append(DRIVE_GAIN * POS_SCALE + COAST_GAIN * (steps[-1] if steps else 0.0))
    hand.sent[0] = (here, np.zeros(3), full)
    assert np.allclose(hand.step_now(0, here + [sum(steps), 0, 0]), [steps[-1], 0, 0])  # as the model said
    assert np.allclose(hand.step_now(0, here + [sum(steps) - 0.02, 0, 0]), [steps[-1] - 0.005, 0, 0])
    hand.sent[0] = (here, np.zeros(3), np.zeros((4, 3)))  # held still, yet the hand moved 4 cm and -2 cm
    assert np.allclose(hand.step_now(0, here + [0.04, -0.02, 0]), [0.01, -0.005, 0])
    controller.act(_obs(here, {}), [build_prompt(INSTRUCTION, sequence_facts(("red",)), PROGRESS_PROMPT_TEMPLATE)])
    before, step, ran = hand.sent[0]
    assert np.allclose(before, here) and ran.shape == (4, 3)  # what ran of this chunk is kept for the next call
    task = make_task("SeqOfColors3-VLA-v0")
    assert replan_interval(task, None, controller) == 4
    with pytest.raises(ValueError, match="over 4 control steps between calls, but 2 would run"):
        replan_interval(task, 2, controller)
    with pytest.raises(ValueError, match="paced_every must be in 1..8"):
        _controller(paced_every=9)


def test_scripted_camera_names_the_tasks_that_have_one():
    from sb3_memret.tasks.mikasa.camera_experts import camera_expert
    from sb3_memret.tasks.mikasa.seq_of_colors.task import SeqOfColorsTask

    assert isinstance(make_controller("scripted-camera", "BunchOfColors5-Long-VLA-v0"), CameraSequenceController)
    assert make_controller("scripted-camera", "BunchOfColors5-VLA-v0").shown_at_once == 5
    with pytest.raises(ValueError, match="has no expert on the cameras alone.*RememberColorTask.*SeqOfColorsTask"):
        make_controller("scripted-camera", "drawer")
    with pytest.raises(ValueError, match="words none"):
        camera_expert(SeqOfColorsTask("SeqOfColors3-VLA-v0", progress=False))


@pytest.mark.slow
def test_through_the_harness_it_plays_a_development_episode_to_success_as_a_protocol_entry(tmp_path):
    """SeqOfColors3 at a development seed: the oracle's facts (with MIKASA's progress counters) and the writer's
    alone (written) each take it to success, reading only the harness's observation (the guard refuses any other
    read while the agent acts), and the table calls it a protocol entry."""
    import json

    from sb3_memret.benchmark import runner

    protocol = runner.Protocol(seed_set="dev", episodes=1, controller="scripted-camera")
    results = runner.run_benchmark(runner.plan(protocol, ["oracle", "written"], env_ids=["SeqOfColors3-VLA-v0"]),
                                   tmp_path, workers=1)
    assert results["privileged_upper_bound"] is False
    assert json.loads((tmp_path / "results.json").read_text())["privileged_upper_bound"] is False
    cells = results["tasks"]["SeqOfColors3-VLA-v0"]["conditions"]
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells
