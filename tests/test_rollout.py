"""What task env a controller gets: camera images for an image controller, or a clear refusal."""

import numpy as np
import pytest

from sb3_memret.controllers.base import ControllerSpec, FrozenController
from sb3_memret.controllers.scripted import ScriptedDrawerController
from sb3_memret.envs.recall import DrawerRecallEnv
from sb3_memret.rollout import evaluate_condition, task_env_kwargs


class CameraController(FrozenController):
    """Stands in for a pi0.5 controller: reads images, never gets to act in these tests."""

    spec = ControllerSpec(action_convention="pd_ee_delta_pose", chunk_len=10, needs_images=True)

    def reset(self, seeds):
        pass

    def reset_envs(self, env_ids, seeds):
        pass

    def _act(self, obs, prompts, parsed):
        return np.zeros((len(prompts), 10, 7))


def test_state_controller_gets_state_and_any_backend():
    assert task_env_kwargs(ScriptedDrawerController()) == {"obs_mode": "state_dict", "render_backend": "none"}
    assert task_env_kwargs(ScriptedDrawerController(), "cpu")["render_backend"] == "cpu"


def test_image_controller_gets_rgb_with_a_backend():
    assert task_env_kwargs(CameraController(), "gpu") == {"obs_mode": "rgb", "render_backend": "gpu"}


def test_image_controller_without_a_backend_is_refused_before_any_env_is_built():
    with pytest.raises(ValueError, match="CameraController needs camera images.*--render-backend cpu or gpu"):
        task_env_kwargs(CameraController())
    with pytest.raises(ValueError, match="needs camera images"):
        evaluate_condition(CameraController(), "oracle", 1)
    with pytest.raises(ValueError, match="needs camera images"):
        DrawerRecallEnv(controller=CameraController())


def test_unknown_backend_is_named():
    with pytest.raises(ValueError, match="unknown render backend 'vulkan'; expected one of"):
        task_env_kwargs(ScriptedDrawerController(), "vulkan")


def test_a_condition_gives_its_facts_at_every_decision_and_an_unknown_one_is_named():
    from sb3_memret.rollout import ConditionFacts
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
