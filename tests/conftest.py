"""Shared fixtures: one real DrawerCubeTakeOut-v1 per test module (building it takes ~1 s)."""

import pytest

from sb3_memret.rollout import make_task_env


@pytest.fixture(scope="module")
def task_env():
    env = make_task_env(robot_init_qpos_noise=0.0)
    yield env
    env.close()
