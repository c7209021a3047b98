"""Physics workers as Ray actors on a local Ray instance: the same episodes as worker processes, and a
killed actor restarted by Ray that replays its episode so no decision is lost or counted twice."""

import logging
import os
import signal

import numpy as np
import pytest
import ray

from sb3_memret.physics.ray_actors import RayPhysics
from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.evaluation.parallel import EpisodeJob, run_jobs
from sb3_memret.tasks.drawer.prompts import condition_prompt


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.WARNING)
    yield
    ray.shutdown()


def test_a_killed_actor_is_restarted_and_replays_its_episode(local_ray, encoder, caplog):
    kwargs = {"encoder": encoder, "max_control_steps": 80}
    on_ray = make_recall_vec_env(2, kwargs, seed=3, backend="ray")
    in_processes = make_recall_vec_env(2, kwargs, seed=3, backend="process")
    physics = on_ray.unwrapped.physics
    assert isinstance(physics, RayPhysics)
    try:
        on_ray.reset(), in_processes.reset()
        with caplog.at_level(logging.WARNING, logger="sb3_memret.physics.ray_actors"):
            for step in range(6):
                if step == 3:  # mid-episode: three chunks executed since the reset
                    os.kill(physics.pids()[1], signal.SIGKILL)
                slots = np.array([[step % 6], [(step + 1) % 6]])
                obs_ray, rewards_ray, dones_ray, infos_ray = on_ray.step(slots)
                obs_proc, rewards_proc, dones_proc, infos_proc = in_processes.step(slots)
                np.testing.assert_allclose(rewards_ray, rewards_proc, atol=1e-7)
                np.testing.assert_array_equal(dones_ray, dones_proc)
                np.testing.assert_array_equal(obs_ray["memories"], obs_proc["memories"])
                assert [i["memory_texts"] for i in infos_ray] == [i["memory_texts"] for i in infos_proc]
        assert [(r.env_id, r.replayed_chunks) for r in physics.restarts] == [(1, 3)]
        assert on_ray.unwrapped.physics_restarts == 1
        assert "physics worker 1 died" in caplog.text and "replayed 3 chunks" in caplog.text
        assert on_ray.unwrapped.controller_calls == 6  # the replay called no controller
    finally:
        on_ray.close()
        in_processes.close()


def test_ablation_episodes_on_ray_actors_play_as_in_one_env(local_ray):
    """run_jobs (ablate) with its physics on Ray actors: the same episodes as one in-process env."""
    jobs = [EpisodeJob(condition_prompt("oracle", layer), 1_000_000 + layer, {"target_layer": layer}) for layer in (1, 2, 3)]
    assert run_jobs("scripted", jobs, "drawer", n_envs=2, backend="ray") == run_jobs("scripted", jobs, "drawer", n_envs=1)
