"""FindImposterColor's touch expert on the harness's inputs alone (``scripted-camera``): it places the cubes only
once more than the cue's are out, touches the colour its prompt does not name, and plays a development episode
through MIKASA's harness as a protocol entry."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, camera_expert_cells

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.base import Episode  # noqa: E402
from sb3_memret.tasks.mikasa.find_imposter.camera_expert import CameraImposterController  # noqa: E402

TASK = "FindImposterColor3-VLA-v0"
ROW = {"red": np.array([0.0, -0.2]), "lime": np.array([0.0, 0.0]), "blue": np.array([0.0, 0.2])}


def _obs(tcp, seen):
    return {"extra": {"tcp_pose": np.array([[*tcp, 0, 1, 0, 0]])}, "sensor_data": {"base_camera": {"rgb": [seen]}}}


def test_it_waits_through_the_cue_s_cubes_then_touches_the_colour_its_prompt_does_not_name():
    task = make_task(TASK)
    controller = make_controller("scripted-camera", TASK)
    assert isinstance(controller, CameraImposterController) and controller.spec.harness_inputs
    assert controller.shown_at_once == 2 and controller.wait_for_all
    controller.read_layout = lambda seen: seen
    controller.reset([0])
    prompt = build_prompt(task.instruction_text, task.oracle_facts(Episode("shown cubes", "blue", ())),
                          task.prompt_template)  # red and lime were shown: blue is the imposter
    ready = np.asarray(controller.gains.ready)
    cue = {"red": np.array([0.0, 0.2]), "lime": np.array([0.0, -0.2])}  # the cue's two, at other places
    chunk = controller.act(_obs(ready, cue), [prompt])[0]
    assert np.abs(chunk[:, :3]).max() < 1e-6 and controller.layouts[0].places == {}  # the cue places nothing
    chunk = controller.act(_obs(ready, ROW), [prompt])[0]
    assert chunk[0, 1] > 0.5  # to blue, at y = +0.2


@pytest.mark.slow
def test_through_the_harness_it_touches_the_imposter_as_a_protocol_entry(tmp_path):
    """FindImposterColor3 at a development seed: the oracle's set and the writer's (written) each take it to
    success, reading only the harness's observation."""
    results, cells = camera_expert_cells(TASK, tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells


@pytest.mark.parametrize("task_id, within", [("FindImposterShape5-VLA-v0", 0.015), ("FindImposterShape9-VLA-v0", 0.035)])
def test_objects_of_several_shapes_are_placed_from_the_frame_that_fills_every_place(task_id, within):
    """Nothing is read while the cue leaves a place empty; FindImposterShape9 at seed 5000 shows no frame with its
    nine apart (touching ones are cut apart); MIKASA counts a touch within 5 cm."""
    from sb3_memret.controllers.base import as_numpy
    from sb3_memret.tasks.mikasa.find_imposter.camera_expert import exemplar_places, imposter_places
    from sb3_memret.tasks.mikasa.find_imposter.perception import task_exemplars

    task = make_task(task_id)
    places_seen = exemplar_places(task_exemplars(task_id), task.n_words)
    gaps = np.linalg.norm(places_seen[:, None] - places_seen[None], axis=-1) + np.eye(task.n_words) * 99
    assert places_seen.shape == (task.n_words, 2) and gaps.min() > 4
    read = imposter_places(task.words, [task.candidate(w) for w in task.words], task_exemplars(task_id))
    env = task.make_env(obs_mode="rgb")
    try:
        obs, _ = env.reset(seed=5000)
        assert read(obs["sensor_data"]["base_camera"]["rgb"]) == {}  # the cue: every object but the imposter
        places = {}
        for _ in range(12):  # the cue (1-5 steps) and the delay (1-5): all are out by then
            obs, *_ = env.step(np.zeros(env.action_space.shape))
            places = read(obs["sensor_data"]["base_camera"]["rgb"])
            if places:
                break
        actors = env.unwrapped.shape_actors
        truth = {task.words[i]: as_numpy(actors[i].pose.p).reshape(-1)[:2] for i in range(task.n_words)}
        assert sorted(places) == sorted(task.words)
        errors = {w: float(np.linalg.norm(p - truth[w])) for w, p in places.items()}
        assert max(errors.values()) < within, errors
    finally:
        env.close()
    with pytest.raises(ValueError, match="128x128"):
        read(np.zeros((64, 64, 3), np.uint8))
