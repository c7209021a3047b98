"""What task env a controller gets: camera images for an image controller, or a clear refusal."""

import numpy as np
import pytest

from sb3_memret.tasks.drawer.prompts import TEMPLATE
from sb3_memret.controllers.base import ControllerSpec, FrozenController
from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
from sb3_memret.envs.recall import DrawerRecallEnv
from sb3_memret.evaluation.rollout import evaluate_task_condition, task_env_kwargs
from sb3_memret.tasks.drawer import DrawerTask

DRAWER = DrawerTask()


class CameraController(FrozenController):
    """Stands in for a pi0.5 controller: reads images, never gets to act in these tests."""

    spec = ControllerSpec(action_convention="pd_ee_delta_pose", chunk_len=10, needs_images=True, prompt_template=TEMPLATE)

    def reset(self, seeds):
        pass

    def reset_envs(self, env_ids, seeds):
        pass

    def _act(self, obs, prompts, parsed):
        return np.zeros((len(prompts), 10, 7))


def test_state_controller_gets_state_and_any_backend():
    assert task_env_kwargs(ScriptedDrawerController(), "none", DRAWER) == {
        "obs_mode": "state_dict", "render_backend": "none", "robot_uids": "panda_light"}
    assert task_env_kwargs(ScriptedDrawerController(), "cpu", DRAWER)["render_backend"] == "cpu"


def test_image_controller_gets_rgb_with_a_backend():
    assert task_env_kwargs(CameraController(), "gpu", DRAWER) == {"obs_mode": "rgb", "render_backend": "gpu",
                                                                  "robot_uids": "panda_light"}


def test_image_controller_without_a_backend_is_refused_before_any_env_is_built():
    with pytest.raises(ValueError, match="CameraController needs camera images.*--render-backend cpu or gpu"):
        task_env_kwargs(CameraController(), "none", DRAWER)
    with pytest.raises(ValueError, match="needs camera images"):
        evaluate_task_condition(CameraController(), "oracle", DRAWER, 1, render_backend="none")
    with pytest.raises(ValueError, match="needs camera images"):
        DrawerRecallEnv(controller=CameraController())


def test_unknown_backend_is_named():
    with pytest.raises(ValueError, match="unknown render backend 'vulkan'; expected one of"):
        task_env_kwargs(ScriptedDrawerController(), "vulkan", DRAWER)


def test_a_condition_gives_its_facts_at_every_decision_and_an_unknown_one_is_named():
    from sb3_memret.evaluation.rollout import ConditionFacts
    from sb3_memret.tasks import make_task
    from sb3_memret.tasks.base import Episode

    task = make_task("drawer")
    episode = Episode("cube", "2", (), {"target_layer": 2})
    oracle, wrong = ConditionFacts(task, "oracle"), ConditionFacts(task, "wrong")
    oracle.start(None, episode)
    wrong.start(None, episode)
    assert [list(oracle.facts(d)) for d in range(3)] == [["the cube is in drawer layer 2."]] * 3
    assert list(wrong.facts(0)) == ["the cube is in drawer layer 3."]
    none = ConditionFacts(task, "none")
    none.start(None, episode)
    assert list(none.facts(0)) == []
    with pytest.raises(ValueError, match="unknown condition 'nonsense'"):
        ConditionFacts(task, "nonsense")
    with pytest.raises(ValueError, match="condition 'written' has no fixed prompt.*WrittenFacts"):
        ConditionFacts(task, "written")


def test_the_drawers_written_condition_plays_the_fixed_prompts_placements():
    """``rollout --condition written`` on the drawer: per layer, at the seeds the fixed prompts play; its writer reads
    the cube's drawer from the simulator's state, so the scripted expert fares as with the oracle fact."""
    import json

    from click.testing import CliRunner

    from sb3_memret.cli import main
    from sb3_memret.evaluation.rollout import WrittenFacts, condition_schedule
    from sb3_memret.tasks import make_task

    assert isinstance(condition_schedule(make_task("drawer"), "written"), WrittenFacts)
    with pytest.raises(ValueError, match=r"unknown condition 'nonsense'; expected one of \['oracle', 'none', 'wrong', "
                                         r"'written'\]"):
        condition_schedule(make_task("drawer"), "nonsense")
    result = CliRunner().invoke(main, ["rollout", "--controller", "scripted", "--condition", "written", "--group", "3",
                                       "--episodes", "1", "--seed", "5", "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output.strip().splitlines()[-1])
    assert summary["seeds"] == [5] and summary["success"] == {"3": 1.0, "overall": 1.0}


def test_the_replan_interval_is_resolved_in_one_place():
    """None is the task's own interval; anything outside [1, the chunk length] is refused, naming whose chunk."""
    assert DRAWER.replan_interval(None, 32) == DRAWER.replan_every == 8
    assert DRAWER.replan_interval(12, 32) == 12
    with pytest.raises(ValueError, match=r"replan_every must be in \[1, 4\] \(the learner's chunk length\), got 8"):
        DRAWER.replan_interval(None, 4, "the learner's")
    with pytest.raises(ValueError, match=r"got 0"):
        DRAWER.replan_interval(0, 32)
