"""RememberShape's and RememberShapeAndColor's touch expert on the harness's inputs alone (``scripted-camera``): the
objects placed and named from the base camera against exemplars of the task's own choice, and an episode through
MIKASA's harness as a protocol entry."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, camera_expert_cells, harness_obs

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.find_imposter.perception import ShapeExemplars  # noqa: E402
from sb3_memret.tasks.mikasa.remember.shape_camera_expert import (  # noqa: E402
    REMEMBER_EXEMPLARS_DIR, CameraShapeTouchController, candidates, exemplars_for, shape_places)


def test_each_remember_task_reads_its_objects_with_exemplars_of_its_own_choice():
    assert exemplars_for("RememberShape5-VLA-v0") == REMEMBER_EXEMPLARS_DIR / "RememberShape5-VLA-v0.npz"
    assert exemplars_for("RememberShape9-Long-VLA-v0") == REMEMBER_EXEMPLARS_DIR / "RememberShape9-VLA-v0.npz"
    with pytest.raises(ValueError, match="RememberColor3-VLA-v0"):
        exemplars_for("RememberColor3-VLA-v0")
    for env_id in ("RememberShape3-VLA-v0", "RememberShape5-VLA-v0", "RememberShape9-VLA-v0",
                   "RememberShapeAndColor3x2-VLA-v0", "RememberShapeAndColor3x3-VLA-v0",
                   "RememberShapeAndColor5x3-VLA-v0"):
        task = make_task(env_id)
        shipped = ShapeExemplars.load(exemplars_for(env_id))
        assert set(shipped.shapes.tolist()) == {shape for _, shape in candidates(env_id, task.words)}, env_id
    assert candidates("RememberShape9-VLA-v0", ["cube", "t shape"]) == [(None, "cube"), (None, "t shape")]
    assert candidates("RememberShapeAndColor5x3-VLA-v0", ["red t shape"]) == [("red", "t shape")]


@pytest.mark.parametrize("env_id, within", [("RememberShape3-VLA-v0", 0.015), ("RememberShapeAndColor3x2-VLA-v0", 0.015),
                                            ("RememberShape9-VLA-v0", 0.035),
                                            ("RememberShapeAndColor5x3-VLA-v0", 0.035)])
def test_the_objects_are_placed_and_named_from_the_base_camera(env_id, within):
    """RememberShape9 at seed 5000: no frame shows its nine apart (FindImposter's reader places none), so touching
    ones are cut apart; MIKASA counts a touch within 5 cm. RememberShapeAndColor5x3 there: FindImposter's exemplars
    (none seen at seven of its fifteen places) swapped the blue cube and sphere."""
    task = make_task(env_id)
    read = shape_places(env_id, task.words)
    env = task.make_env(obs_mode="rgb")
    try:
        obs, _ = env.reset(seed=5000)
        places = {}
        for _ in range(12):  # the cue alone, the delay, then all N out
            places = read(as_numpy(obs["sensor_data"]["base_camera"]["rgb"]))
            if places:
                break
            obs, *_ = env.step(np.zeros(env.action_space.shape))
        base = env.unwrapped
        actors = [base.shape_actors[i] for i in sorted(base.shape_actors)]
        assert sorted(places) == sorted(task.words)
        for word, actor in zip(task.words, actors):
            assert np.linalg.norm(places[word] - as_numpy(actor.pose.p).reshape(-1)[:2]) < within, word
    finally:
        env.close()


def test_it_heads_for_the_object_its_prompt_names_once_all_are_placed():
    task = make_task("RememberShape3-VLA-v0")
    layout = {"cube": np.array([0.0, -0.2]), "sphere": np.array([0.0, 0.0]), "cylinder": np.array([0.0, 0.2])}
    controller = CameraShapeTouchController(task.words, task.template, "shape", paced_every=4,
                                            read_layout=lambda frame: frame)
    assert controller.spec.harness_inputs and controller.field == "shape"
    controller.reset([0])
    prompt = build_prompt(task.instruction_text, [task.cue_fact.format(shape="cylinder")], task.template)
    chunk = controller.act(harness_obs([0.0, 0.0, 0.2], 0.08, layout), [prompt])[0]
    assert chunk[0, 1] > 0.5  # toward the cylinder, at +y
    assert isinstance(make_controller("scripted-camera", "RememberShapeAndColor3x3-VLA-v0"),
                      CameraShapeTouchController)


@pytest.mark.slow
def test_through_the_harness_it_touches_the_remembered_shape_as_a_protocol_entry(tmp_path):
    """RememberShape3 at a development seed: the oracle's shape and the writer's (written) each lead to success,
    reading only the harness's observation."""
    results, cells = camera_expert_cells("RememberShape3-VLA-v0", tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells
