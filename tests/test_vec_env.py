"""make_recall_vec_env: worker processes for several envs, the retention push reaching each."""

import os
import signal

import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.policy.networks import RetentionScorer
from sb3_memret.workers import WorkerDiedError

SHORT = {"max_control_steps": 16}


def test_two_envs_run_in_workers_and_receive_retention_weights():
    venv = make_recall_vec_env(2, SHORT, seed=7)
    try:
        assert isinstance(venv.venv, SubprocVecEnv)
        obs = venv.reset()
        assert obs["memories"].shape == (2, 6, 384) and obs["mask"].shape == (2, 6)
        assert not np.array_equal(obs["memories"][0], obs["memories"][1])  # seeds 7 and 8 differ
        weights = RetentionScorer().state_dict()
        venv.env_method("set_retention_weights", weights)
        assert all(r is not None for r in venv.get_attr("retention"))
        for _ in range(2):
            obs, rewards, dones, infos = venv.step(np.zeros((2, 1), dtype=np.int64))
        assert dones.all() and all("episode" in info for info in infos)  # VecMonitor saw both episodes end
    finally:
        venv.close()


def test_one_env_stays_in_process_and_bad_counts_are_refused():
    venv = make_recall_vec_env(1, SHORT)
    try:
        assert isinstance(venv.venv, DummyVecEnv)
    finally:
        venv.close()
    with pytest.raises(ValueError, match="n_envs must be >= 1, got 0"):
        make_recall_vec_env(0)


def test_a_killed_worker_is_named_and_the_rest_shut_down():
    """SIGKILL one worker (what the out-of-memory killer does): the next step names it, its pid and
    the signal, and close() still ends the live worker."""
    venv = make_recall_vec_env(2, env_id="CartPole-v1")  # a light env: the workers are what is tested
    workers = venv.venv.processes
    try:
        venv.reset()
        os.kill(workers[1].pid, signal.SIGKILL)
        workers[1].join(timeout=10)
        with pytest.raises(WorkerDiedError, match=rf"^env worker 1 \(pid {workers[1].pid}\) killed by SIGKILL"):
            venv.step(np.zeros(2, dtype=np.int64))
    finally:
        venv.close()
    assert not any(p.is_alive() for p in workers)


def test_workers_leave_stop_signals_to_the_trainer():
    """Ctrl-C and a scheduler's SIGTERM reach every process of the group; workers ignore both, so the
    trainer can checkpoint and then close them."""
    venv = make_recall_vec_env(2, env_id="CartPole-v1")
    try:
        venv.reset()
        for worker in venv.venv.processes:
            os.kill(worker.pid, signal.SIGTERM)
            os.kill(worker.pid, signal.SIGINT)
        obs, *_ = venv.step(np.zeros(2, dtype=np.int64))
        assert obs.shape == (2, 4) and all(p.is_alive() for p in venv.venv.processes)
    finally:
        venv.close()
    assert not any(p.is_alive() for p in venv.venv.processes)
