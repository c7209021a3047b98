"""Vectorised DrawerRecall-v0 for SB3: one process per env when there are several."""

from __future__ import annotations

from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any, Callable

import gymnasium as gym
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecMonitor

from sb3_memret.workers import START_METHOD, WorkerDiedError, exit_description, init_worker_process

CLOSE_TIMEOUT = 10.0  # seconds a worker gets to finish its step and exit


def _env_factory(env_id: str, env_kwargs: dict[str, Any], in_worker: bool) -> Callable[[], gym.Env]:
    def make() -> gym.Env:
        import sb3_memret.envs  # noqa: F401  (registers the env ids in a fresh worker process)

        if in_worker:
            init_worker_process()
        return gym.make(env_id, **env_kwargs)

    return make


class _WatchedPipe:
    """The parent's end of a worker pipe that names the worker when it is gone."""

    def __init__(self, conn: Connection, process: BaseProcess, index: int):
        self.conn, self.process, self.index = conn, process, index

    def died(self, doing: str) -> WorkerDiedError:
        return WorkerDiedError(f"env worker {self.index} (pid {self.process.pid}) {exit_description(self.process)} "
                               f"{doing}")

    def send(self, message: Any) -> None:
        try:
            self.conn.send(message)
        except (EOFError, OSError) as err:
            raise self.died("before it could take a command") from err

    def recv(self) -> Any:
        try:
            return self.conn.recv()
        except (EOFError, OSError) as err:
            raise self.died("before it answered") from err

    def close(self) -> None:
        self.conn.close()


class WatchedSubprocVecEnv(SubprocVecEnv):
    """``SubprocVecEnv`` whose dead workers are reported by env index, pid and exit signal
    (``WorkerDiedError``) instead of a bare EOFError, and whose ``close`` shuts the live workers
    down cleanly after an interrupt or a dead sibling."""

    def __init__(self, env_fns: list[Callable[[], gym.Env]], start_method: str = START_METHOD):
        try:
            super().__init__(env_fns, start_method=start_method)
        except (EOFError, OSError) as err:  # worker 0 failed to build its env (its traceback is above)
            self._watch()
            error = self.remotes[0].died("while building its env")
            self.close()
            raise error from err
        self._watch()

    def _watch(self) -> None:
        self.remotes = [_WatchedPipe(r, p, i) for i, (r, p) in enumerate(zip(self.remotes, self.processes))]

    def close(self) -> None:
        """Tell every live worker to close, wait for it, then close the pipes.

        Unlike SB3's ``close`` this never waits for a step's replies: after an interrupt inside
        ``step_wait`` some are already read and some are not, and reading one that never comes
        would hang. A worker answers a pending step, reads "close" and exits before its pipe is
        closed here, so nothing it sent is cut off under it.
        """
        if self.closed:
            return
        for remote, process in zip(self.remotes, self.processes):
            if process.is_alive():
                try:
                    remote.send(("close", None))
                except WorkerDiedError:
                    pass
        for process in self.processes:
            process.join(timeout=CLOSE_TIMEOUT)
            if process.is_alive():  # workers ignore SIGTERM
                process.kill()
                process.join()
        for remote in self.remotes:
            remote.close()
        self.closed = True


def make_recall_vec_env(
    n_envs: int = 1,
    env_kwargs: dict[str, Any] | None = None,
    seed: int | None = None,
    env_id: str | None = None,
    subprocess: bool | None = None,
) -> VecEnv:
    """``n_envs`` copies of DrawerRecall-v0 behind a ``VecMonitor`` (episode return/length logs).

    Several envs run in ``WatchedSubprocVecEnv`` workers (each builds its own simulator and
    controller), one env in-process; ``subprocess`` overrides that choice. Env ``i`` is seeded
    with ``seed + i``.
    """
    from sb3_memret.envs import RECALL_ENV_ID

    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    use_workers = n_envs > 1 if subprocess is None else subprocess
    factories = [_env_factory(env_id or RECALL_ENV_ID, dict(env_kwargs or {}), use_workers) for _ in range(n_envs)]
    venv = WatchedSubprocVecEnv(factories) if use_workers else DummyVecEnv(factories)
    if seed is not None:
        venv.seed(seed)
    return VecMonitor(venv)


__all__ = ["WatchedSubprocVecEnv", "make_recall_vec_env"]
