"""Physics workers as Ray actors: the same decision env on one machine or on a Ray cluster.

Each task env lives in a Ray actor (``TaskRunner`` inside), placed with Ray's SPREAD strategy.
The trainer keeps, per env, the episode's seed, reset options and every chunk executed since
the reset. When an actor dies, Ray restarts it (``max_restarts``) and the trainer replays the
episode on the new actor (reset with the same seed, the same chunks, no controller calls),
checks that the replay reached the state the dead actor last reported, and then repeats the
command that was lost. So no decision is lost or counted twice; each restart is logged and
kept in ``RayPhysics.restarts``.

Every node of a cluster needs sb3-memret installed (the same environment as the trainer).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from sb3_memret.tasks import Task
from sb3_memret.tasks.base import EnvFrame
from sb3_memret.physics.backends import PhysicsBackend, ResetRequest, TaskEnvInfo, TaskRunner
from sb3_memret.common.workers import WorkerDiedError

logger = logging.getLogger(__name__)
MAX_RESTARTS = 3  # restarts Ray grants each physics actor
RESTART_TIMEOUT = 300.0  # seconds to wait for Ray to bring a dead actor back
REPLAY_ATOL = 1e-5  # how close (m, rad) a replayed episode must land to the state the dead actor reported


class PhysicsActor:
    """One task env in a Ray actor process (wrapped by ``ray.remote`` when a ``RayPhysics`` starts)."""

    def __init__(self, task_kwargs: dict[str, Any], max_control_steps: int, task: Task | str):
        import os

        import torch

        torch.set_num_threads(1)  # several actors share a node's cores
        self.runner = TaskRunner(task_kwargs, max_control_steps, task)
        self._pid = os.getpid()

    def pid(self) -> int:
        return self._pid

    def info(self) -> TaskEnvInfo:
        return self.runner.info()

    def reset(self, seed: int, options: dict[str, Any]) -> EnvFrame:
        return self.runner.reset(seed, options)

    def execute(self, actions: np.ndarray) -> EnvFrame:
        return self.runner.execute(actions)

    def replay(self, seed: int, options: dict[str, Any], chunks: list[np.ndarray]) -> EnvFrame:
        return self.runner.replay(seed, options, chunks)


@dataclass
class EpisodeLog:
    """What it takes to rebuild one env's episode on a fresh actor."""

    seed: int
    options: dict[str, Any]
    chunks: list[np.ndarray] = field(default_factory=list)
    last: EnvFrame | None = None


@dataclass(frozen=True)
class Restart:
    """A physics actor that died and was restarted: which env, why, and how much it replayed."""

    env_id: int
    error: str
    replayed_chunks: int


class RayPhysics(PhysicsBackend):
    """``num_envs`` task envs in Ray actors, on the Ray instance at ``address`` (a local one if None and
    none is running; ``ray.init`` also reads ``RAY_ADDRESS``)."""

    def __init__(self, num_envs: int, task_kwargs: Mapping[str, Any], max_control_steps: int,
                 address: str | None = None, max_restarts: int = MAX_RESTARTS, *, task: Task | str):
        import ray

        if not ray.is_initialized():
            ray.init(address=address, include_dashboard=False, logging_level=logging.WARNING)
        # a one-machine Ray instance runs its actors on the trainer's cores
        self.shares_cores = len(ray.nodes()) == 1
        self.num_envs, self.max_restarts = num_envs, max_restarts
        actor_class = ray.remote(max_restarts=max_restarts, max_task_retries=0,
                                 scheduling_strategy="SPREAD")(PhysicsActor)
        self.actors = [actor_class.remote(dict(task_kwargs), max_control_steps, task) for _ in range(num_envs)]
        self.logs: list[EpisodeLog | None] = [None] * num_envs
        self.restarts: list[Restart] = []
        self.closed = False
        self.env_info = self._gather({0: lambda i: self.actors[i].info.remote()})[0]

    def reset(self, requests: Sequence[ResetRequest]) -> dict[int, EnvFrame]:
        by_env = {r.env_id: r for r in requests}
        frames = self._gather({i: (lambda i: self.actors[i].reset.remote(by_env[i].seed, dict(by_env[i].options)))
                               for i in by_env})
        for i, frame in frames.items():
            self.logs[i] = EpisodeLog(by_env[i].seed, dict(by_env[i].options), last=frame)
        return frames

    def execute(self, chunks: Mapping[int, np.ndarray]) -> dict[int, EnvFrame]:
        chunks = {i: np.asarray(chunk) for i, chunk in chunks.items()}
        frames = self._gather({i: (lambda i: self.actors[i].execute.remote(chunks[i])) for i in chunks},
                              catch_up=True)
        for i, frame in frames.items():
            log = self.logs[i]
            assert log is not None, "execute before reset"
            log.chunks.append(chunks[i])
            log.last = frame
        return frames

    def pids(self) -> list[int]:
        """The process id of every physics actor (for tests that kill one)."""
        import ray

        return ray.get([actor.pid.remote() for actor in self.actors])

    def _gather(self, submit: Mapping[int, Callable[[int], Any]], catch_up: bool = False) -> dict[Any, Any]:
        """Submit every env's command, then collect the answers; an env whose actor died is caught up
        on the restarted actor (``catch_up``: its episode replayed) and its command submitted again."""
        import ray

        from ray.exceptions import RayActorError

        refs = {i: make(i) for i, make in submit.items()}
        results = {}
        for i, ref in refs.items():
            last_error = ""
            for attempt in range(self.max_restarts + 1):
                try:
                    if attempt:
                        self._wait_alive(i)
                        replayed = self._catch_up(i) if catch_up else 0
                        ref = submit[i](i)
                        self._note_restart(i, last_error, replayed)
                    results[i] = ray.get(ref)
                    break
                except RayActorError as err:  # died, or restarting (ActorUnavailableError)
                    last_error = str(err).splitlines()[0]
                    if attempt == self.max_restarts:
                        raise WorkerDiedError(f"physics worker {i} (Ray actor) died {attempt + 1} times; last: "
                                              f"{last_error}") from err
        return results

    def _wait_alive(self, i: int) -> None:
        """Block until Ray has restarted env ``i``'s actor (it answers), or fail after ``RESTART_TIMEOUT``."""
        import ray
        from ray.exceptions import ActorUnavailableError

        deadline = time.monotonic() + RESTART_TIMEOUT
        while True:
            try:
                ray.get(self.actors[i].pid.remote())
                return
            except ActorUnavailableError:
                if time.monotonic() > deadline:
                    raise WorkerDiedError(f"physics worker {i} (Ray actor) was not back {RESTART_TIMEOUT:.0f} s "
                                          "after it died") from None
                time.sleep(0.2)

    def _catch_up(self, i: int) -> int:
        """Replay env ``i``'s episode on its restarted actor and check it lands where the dead one was."""
        import ray

        log = self.logs[i]
        if log is None:
            return 0
        frame = ray.get(self.actors[i].replay.remote(log.seed, log.options, log.chunks))
        expected = log.last
        for name in ("eef_pos", "target_pos", "drawer_qpos"):
            if not np.allclose(getattr(frame.state, name), getattr(expected.state, name), atol=REPLAY_ATOL):
                raise RuntimeError(f"physics worker {i}: replaying episode seed {log.seed} ({len(log.chunks)} chunks) "
                                   f"on the restarted actor reached {name}={getattr(frame.state, name).tolist()}, not "
                                   f"{getattr(expected.state, name).tolist()}: the simulation is not deterministic "
                                   "here, so the episode cannot be resumed")
        return len(log.chunks)

    def _note_restart(self, i: int, error: str, replayed: int) -> None:
        self.restarts.append(Restart(i, error, replayed))
        logger.warning("physics worker %d died (%s); Ray restarted it and it replayed %d chunks of its episode",
                       i, error, replayed)

    def close(self) -> None:
        """Kill this backend's actors (Ray itself stays up for whoever started it)."""
        import ray

        if self.closed:
            return
        self.closed = True
        if ray.is_initialized():
            for actor in self.actors:
                ray.kill(actor, no_restart=True)


__all__ = ["EpisodeLog", "MAX_RESTARTS", "PhysicsActor", "RayPhysics", "Restart"]
