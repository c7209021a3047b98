"""Controller episodes spread over worker processes, each with its own task env and controller.

The CPU simulator runs one env per process, so parallel evaluation means processes: every
worker builds DrawerCubeTakeOut-v1 and the controller from its spec string once, then plays
the episodes it is handed. Results come back in job order whatever order they finish in.
"""

from __future__ import annotations

import multiprocessing
import signal
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Callable, Sequence

import gymnasium as gym

from sb3_memret.controllers import make_controller
from sb3_memret.controllers.base import FrozenController
from sb3_memret.rollout import DEFAULT_REPLAN_EVERY, EpisodeResult, make_task_env, run_episode, task_env_kwargs
from sb3_memret.workers import START_METHOD, WorkerDiedError, init_worker_process


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to play: the cube's layer and placement seed, the prompt, the replan interval."""

    prompt: str
    layer: int
    seed: int
    replan_every: int = DEFAULT_REPLAN_EVERY


class _Player:
    """A task env and a controller that play jobs one after another."""

    def __init__(self, controller: str, render_backend: str):
        self.controller: FrozenController = make_controller(controller)
        self.env: gym.Env = make_task_env(**task_env_kwargs(self.controller, render_backend))
        self.controller.check_env(self.env)

    def play(self, job: EpisodeJob) -> EpisodeResult:
        return run_episode(self.env, self.controller, job.prompt, job.seed, job.layer, job.replan_every)

    def close(self) -> None:
        self.env.close()


_worker_player: _Player | None = None


def _init_worker(controller: str, render_backend: str) -> None:
    global _worker_player
    # SIGTERM stays fatal: a broken ProcessPoolExecutor ends its remaining workers with it.
    init_worker_process(ignored=(signal.SIGINT,))
    _worker_player = _Player(controller, render_backend)


def _play_in_worker(job: EpisodeJob) -> EpisodeResult:
    assert _worker_player is not None, "worker used before its initializer ran"
    return _worker_player.play(job)


def run_jobs(
    controller: str,
    jobs: Sequence[EpisodeJob],
    n_envs: int = 1,
    render_backend: str = "none",
    on_result: Callable[[EpisodeJob, EpisodeResult], None] | None = None,
) -> list[EpisodeResult]:
    """Play ``jobs`` with ``n_envs`` envs (worker processes when > 1); results in job order."""
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    if not jobs:
        return []
    if n_envs == 1:
        player = _Player(controller, render_backend)
        try:
            too_long = sorted({job.replan_every for job in jobs if job.replan_every > player.controller.spec.chunk_len})
            if too_long:
                raise ValueError(f"the controller's chunk length is {player.controller.spec.chunk_len}; replan "
                                 f"intervals {too_long} exceed it")
            results = []
            for job in jobs:
                results.append(player.play(job))
                if on_result is not None:
                    on_result(job, results[-1])
            return results
        finally:
            player.close()
    results: list[EpisodeResult | None] = [None] * len(jobs)
    context = multiprocessing.get_context(START_METHOD)
    with ProcessPoolExecutor(min(n_envs, len(jobs)), mp_context=context, initializer=_init_worker,
                             initargs=(controller, render_backend)) as pool:
        pending: dict[Future, int] = {pool.submit(_play_in_worker, job): i for i, job in enumerate(jobs)}
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    i = pending.pop(future)
                    results[i] = future.result()
                    if on_result is not None:
                        on_result(jobs[i], results[i])
        except BrokenProcessPool as err:  # a worker was killed (out of memory, a signal)
            raise WorkerDiedError(f"an episode worker process died while playing: {err}") from err
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    return results  # type: ignore[return-value]


__all__ = ["EpisodeJob", "run_jobs"]
