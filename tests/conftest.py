"""Shared fixtures: the MiniLM encoder, one real DrawerCubeTakeOut-v1 per test module (building it takes ~1 s), one with
both cameras rendered by the CPU renderer per session, and SB3's default log folder and the project's cache inside
pytest's temporary directory rather than the system's."""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from sb3_memret.physics.backends import TaskRunner
from sb3_memret.evaluation.rollout import EpisodeResult, play_episode
from sb3_memret.tasks.drawer import DrawerTask


def make_task_env(**kwargs):
    """DrawerCubeTakeOut-v1 as a frozen controller consumes it (state, no renderer unless asked)."""
    return DrawerTask().make_env(**kwargs)


def drawer_episode(env, controller, prompt: str, seed: int, layer: int, replan_every: int | None = None,
                   check_prompt: bool = True) -> EpisodeResult:
    """One drawer episode in ``env`` with the cube in ``layer`` and ``prompt`` at every decision (the task's one
    episode runner, ``rollout.play_episode``)."""
    return play_episode(TaskRunner.around(env, DrawerTask()), controller, seed, prompt, replan_every,
                        {"target_layer": layer}, check_prompt)


@pytest.fixture(scope="session", autouse=True)
def sb3_log_folder(tmp_path_factory):
    """A ``learn`` without its own logger makes an SB3-<date> folder under $SB3_LOGDIR or /tmp."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3_logs")))
        yield


@pytest.fixture(scope="session", autouse=True)
def project_cache(tmp_path_factory):
    """The project's cache (the light Panda's meshes, trunk features), made afresh for the session."""
    from sb3_memret.common.cache import CACHE_ENV

    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(CACHE_ENV, str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture(scope="session")
def encoder():
    """MiniLM, loaded once (it caches encodings by text)."""
    from sb3_memret.memory.encoder import MiniLMEncoder

    return MiniLMEncoder()


@pytest.fixture(scope="module")
def task_env():
    env = make_task_env(robot_init_qpos_noise=0.0)
    yield env
    env.close()


@pytest.fixture(scope="module")
def objects_env():
    """DrawerCubeTakeOut-v1 with three objects of the training set, one per drawer."""
    from sb3_memret.tasks.drawer.objects import OBJECT_SETS

    env = make_task_env(robot_init_qpos_noise=0.0, objects=OBJECT_SETS["train"], n_objects=3)
    yield env
    env.close()


@pytest.fixture(scope="session")
def rgb_task_env():
    """DrawerCubeTakeOut-v1 with both 224x224 cameras, rendered on the CPU by the project's lavapipe
    (``make renderer``; missing, it fails with the command to run)."""
    env = make_task_env(obs_mode="rgb", render_backend="cpu", robot_init_qpos_noise=0.0)
    yield env
    env.close()


@pytest.fixture(scope="session")
def load_script():
    """Import a script of ``scripts/`` by name as a module, for tests of its functions."""
    return _load_script


def _load_script(name: str) -> ModuleType:
    path = Path(__file__).resolve().parents[1] / "scripts" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # a script's dataclasses find their module by name
    spec.loader.exec_module(module)
    return module
