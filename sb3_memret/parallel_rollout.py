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
from typing import Callable, Sequence, TypeVar

import gymnasium as gym

from sb3_memret.controllers import make_controller
from sb3_memret.controllers.base import FrozenController
from sb3_memret.rollout import DEFAULT_REPLAN_EVERY, EpisodeResult, make_task_env, run_episode, task_env_kwargs
from sb3_memret.workers import START_METHOD, WorkerDiedError, init_worker_process

J = TypeVar("J")
R = TypeVar("R")


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to play: the cube's layer and placement seed, the prompt, the replan interval."""

    prompt: str
    layer: int
    seed: int
    replan_every: int = DEFAULT_REPLAN_EVERY
    check_prompt: bool = True  # False only where an ablation measures untrained wording


class _Player:
    """A task env and a controller that play jobs one after another."""

    def __init__(self, controller: str, render_backend: str):
        self.controller: FrozenController = make_controller(controller)
        self.env: gym.Env = make_task_env(**task_env_kwargs(self.controller, render_backend))
        self.controller.check_env(self.env)

    def play(self, job: EpisodeJob) -> EpisodeResult:
        return run_episode(self.env, self.controller, job.prompt, job.seed, job.layer, job.replan_every,
                           job.check_prompt)

    def close(self) -> None:
        self.env.close()


_worker_player: _Player | None = None


def _init_worker(controller: str, render_backend: str, in_worker: bool = True) -> None:
    global _worker_player
    if in_worker:
        init_pool_worker()
    _worker_player = _Player(controller, render_backend)


def _play_in_worker(job: EpisodeJob) -> EpisodeResult:
    assert _worker_player is not None, "worker used before its initializer ran"
    return _worker_player.play(job)


def init_pool_worker() -> None:
    """Set up a pool worker process: SIGINT ignored (the parent handles it), SIGTERM left fatal, since a
    broken ProcessPoolExecutor ends its remaining workers with it."""
    init_worker_process(ignored=(signal.SIGINT,))


def run_jobs(
    controller: str,
    jobs: Sequence[EpisodeJob],
    n_envs: int = 1,
    render_backend: str = "none",
    on_result: Callable[[EpisodeJob, EpisodeResult], None] | None = None,
) -> list[EpisodeResult]:
    """Play ``jobs`` with ``n_envs`` envs (worker processes when > 1); results in job order."""
    global _worker_player
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    try:
        return map_in_workers(_init_worker, (controller, render_backend), _play_in_worker, jobs, n_envs, on_result)
    finally:
        if _worker_player is not None:  # the in-process player of n_envs == 1
            _worker_player.close()
            _worker_player = None


def map_in_workers(
    initializer: Callable[..., None],
    initargs: tuple,
    work: Callable[[J], R],
    jobs: Sequence[J],
    n_workers: int = 1,
    on_result: Callable[[J, R], None] | None = None,
) -> list[R]:
    """``[work(job) for job in jobs]`` after ``initializer(*initargs)``: in this process when ``n_workers``
    is 1, else in that many spawned worker processes; results in job order, ``on_result`` as each arrives."""
    if n_workers < 1:
        raise ValueError(f"n_workers must be >= 1, got {n_workers}")
    if not jobs:
        return []
    if n_workers == 1:
        initializer(*initargs, in_worker=False)
        results_here = []
        for job in jobs:
            results_here.append(work(job))
            if on_result is not None:
                on_result(job, results_here[-1])
        return results_here
    results: list[R | None] = [None] * len(jobs)
    context = multiprocessing.get_context(START_METHOD)
    with ProcessPoolExecutor(min(n_workers, len(jobs)), mp_context=context, initializer=initializer,
                             initargs=initargs) as pool:
        pending: dict[Future, int] = {pool.submit(work, job): i for i, job in enumerate(jobs)}
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    i = pending.pop(future)
                    results[i] = future.result()
                    if on_result is not None:
                        on_result(jobs[i], results[i])
        except BrokenProcessPool as err:  # a worker was killed (out of memory, a signal)
            raise WorkerDiedError(f"a worker process died while playing: {err}") from err
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    return results  # type: ignore[return-value]


__all__ = ["EpisodeJob", "init_pool_worker", "map_in_workers", "run_jobs"]
