"""Vectorised DrawerRecall-v0 for SB3: one process per env when there are several."""

from __future__ import annotations

import signal
from typing import Any, Callable

import gymnasium as gym
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecMonitor


def _env_factory(env_id: str, env_kwargs: dict[str, Any], in_worker: bool) -> Callable[[], gym.Env]:
    def make() -> gym.Env:
        import sb3_memret.envs  # noqa: F401  (registers the env ids in a fresh worker process)

        if in_worker:
            # Ctrl-C belongs to the trainer, which saves a checkpoint and then closes the workers;
            # one torch thread per worker keeps n workers from oversubscribing the cores.
            import torch

            signal.signal(signal.SIGINT, signal.SIG_IGN)
            torch.set_num_threads(1)
        return gym.make(env_id, **env_kwargs)

    return make


def make_recall_vec_env(
    n_envs: int = 1,
    env_kwargs: dict[str, Any] | None = None,
    seed: int | None = None,
    env_id: str | None = None,
    subprocess: bool | None = None,
) -> VecEnv:
    """``n_envs`` copies of DrawerRecall-v0 behind a ``VecMonitor`` (episode return/length logs).

    Several envs run in ``SubprocVecEnv`` workers (each builds its own simulator and
    controller), one env in-process; ``subprocess`` overrides that choice. Env ``i`` is seeded
    with ``seed + i``.
    """
    from sb3_memret.envs import RECALL_ENV_ID

    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    use_workers = n_envs > 1 if subprocess is None else subprocess
    factories = [_env_factory(env_id or RECALL_ENV_ID, dict(env_kwargs or {}), use_workers) for _ in range(n_envs)]
    venv = SubprocVecEnv(factories, start_method="forkserver") if use_workers else DummyVecEnv(factories)
    if seed is not None:
        venv.seed(seed)
    return VecMonitor(venv)


__all__ = ["make_recall_vec_env"]
