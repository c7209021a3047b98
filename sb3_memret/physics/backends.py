"""The physics backends that run on this machine, and the task runner every CPU worker holds.

The trainer keeps the memory banks, the writers, the encoder and ONE frozen controller; the
task envs live in a physics backend that resets them and executes
action chunks, and answers with an ``EnvFrame`` per env: what the controller will observe,
the privileged state the writer reads, the potential and how the chunk ended.

Backends: ``InProcessPhysics`` (task envs in this process: one env, tests), ``ProcessPhysics``
(one spawned worker process per env on the CPU), ``BatchedSimPhysics`` (one ManiSkill env with
``num_envs=N``, for ``sim_backend="gpu"``); ``RayPhysics`` (Ray actors) is in ``ray_actors``.
"""

from __future__ import annotations

import multiprocessing
import weakref
from abc import ABC, abstractmethod
from contextlib import nullcontext
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np

from sb3_memret.controllers.base import env_robot
from sb3_memret.common.obs_trees import to_numpy
from sb3_memret.physics.chunks import execute_chunk
from sb3_memret.physics.sensor_gate import sensors_pause
from sb3_memret.tasks import Task, make_task
from sb3_memret.tasks.base import EnvFrame
from sb3_memret.common.workers import START_METHOD, WorkerDiedError, exit_description, init_worker_process

BACKENDS = ("auto", "inprocess", "process", "gpu", "ray")
CLOSE_TIMEOUT = 10.0  # seconds a worker gets to finish its chunk and exit


@dataclass(frozen=True)
class TaskEnvInfo:
    """What a controller checks a task env against (``FrozenController.check_env``)."""

    control_mode: str
    obs_mode: str
    robot: str | None = None  # the ManiSkill robot uid the env simulates and renders

    @classmethod
    def of(cls, env: Any) -> "TaskEnvInfo":
        base = env.unwrapped
        return cls(str(base.control_mode), str(base.obs_mode), env_robot(base))


@dataclass(frozen=True)
class ResetRequest:
    """Start env ``env_id``'s next episode from ``seed`` with these reset options (e.g. ``target_layer``)."""

    env_id: int
    seed: int
    options: Mapping[str, Any] = field(default_factory=dict)


class TaskRunner:
    """One env of a task that resets and plays chunks: what every CPU physics worker runs. It keeps
    the episode's success once (a task whose episodes go on after success, as MIKASA's do, counts it)."""

    def __init__(self, task_kwargs: Mapping[str, Any], max_control_steps: int, task: Task | str):
        from sb3_memret.physics.grasp_memo import install_grasp_memo

        install_grasp_memo()  # repeated grasp checks answered once per physics step (the same answers, faster)
        task = make_task(task)
        self._start(task, task.make_env(max_episode_steps=max_control_steps, **task_kwargs))

    @classmethod
    def around(cls, env: gym.Env, task: Task | str) -> "TaskRunner":
        """A runner of ``env``, an env of ``task`` made elsewhere (a test's shared env): closing it closes ``env``."""
        runner = cls.__new__(cls)
        runner._start(make_task(task), env)
        return runner

    def _start(self, task: Task, env: gym.Env) -> None:
        self.task, self.env = task, env
        self.succeeded = False
        self.steps = 0  # control steps since the reset
        # the steps from a reset the writer perceives (``Task.perception_window``; None: all of them)
        self.window = self.task.perception_window(self.env) if self.task.perceives_every_step else None

    def info(self) -> TaskEnvInfo:
        return TaskEnvInfo.of(self.env)

    def reset(self, seed: int, options: Mapping[str, Any]) -> EnvFrame:
        obs, info = self.env.reset(seed=int(seed), options=dict(options))
        frame, = self.task.frames(self.env, obs, info, reset=True)
        self.succeeded, self.steps = frame.success, 0
        if self.task.perceives_every_step:
            frame.percepts = [self.task.perceive(self.env, obs)]
        return frame

    def execute(self, actions: np.ndarray) -> EnvFrame:
        perceive = self.task.perceive if self.task.perceives_every_step else None
        window = None if self.window is None else self.window - self.steps - 1  # its steps left in this chunk
        outcome = execute_chunk(self.env, actions, perceive, window)
        self.steps += outcome.steps
        frame, = self.task.frames(self.env, outcome.obs, outcome.info)
        self.succeeded = self.succeeded or outcome.succeeded or frame.success
        frame.success, frame.steps, frame.reward, frame.percepts = self.succeeded, outcome.steps, outcome.reward, \
            outcome.percepts
        frame.terminated = outcome.terminated or (self.task.ends_at_success and self.succeeded)
        frame.truncated = outcome.truncated
        return frame

    def replay(self, seed: int, options: Mapping[str, Any], chunks: Sequence[np.ndarray]) -> EnvFrame:
        """Play an episode again from its seed and its executed chunks (a restarted worker catching up)."""
        frame = self.reset(seed, options)
        for chunk in chunks:
            frame = self.execute(chunk)
        return frame

    def close(self) -> None:
        self.env.close()


class PhysicsBackend(ABC):
    """``num_envs`` task envs somewhere: reset some, execute a chunk in some, answer with frames."""

    num_envs: int
    env_info: TaskEnvInfo
    shares_cores: bool = False  # whether its workers compute on this machine's cores beside the trainer

    @abstractmethod
    def reset(self, requests: Sequence[ResetRequest]) -> dict[int, EnvFrame]:
        """Reset the requested envs; frames keyed by env id."""

    @abstractmethod
    def execute(self, chunks: Mapping[int, np.ndarray]) -> dict[int, EnvFrame]:
        """Execute ``chunks[i]`` (steps, action_dim) in env i, all envs at once; frames keyed by env id."""

    @abstractmethod
    def close(self) -> None:
        """Release the envs (and any workers)."""


class InProcessPhysics(PhysicsBackend):
    """Task envs in this process, one after another: no start-up cost, no parallelism."""

    def __init__(self, num_envs: int, task_kwargs: Mapping[str, Any], max_control_steps: int, task: Task | str):
        self.num_envs = num_envs
        self.runners = [TaskRunner(task_kwargs, max_control_steps, task) for _ in range(num_envs)]
        self.env_info = self.runners[0].info()

    def reset(self, requests: Sequence[ResetRequest]) -> dict[int, EnvFrame]:
        return {r.env_id: self.runners[r.env_id].reset(r.seed, r.options) for r in requests}

    def execute(self, chunks: Mapping[int, np.ndarray]) -> dict[int, EnvFrame]:
        return {i: self.runners[i].execute(chunk) for i, chunk in chunks.items()}

    def close(self) -> None:
        for runner in self.runners:
            runner.close()


def _process_worker(conn: Connection, task_kwargs: dict[str, Any], max_control_steps: int, task: Task | str) -> None:
    """A physics worker's loop: build the task env, then answer ("reset"|"execute"|"close", args)."""
    init_worker_process()
    runner = TaskRunner(task_kwargs, max_control_steps, task)
    conn.send(runner.info())
    try:
        while True:
            command, args = conn.recv()
            if command == "close":
                break
            conn.send(getattr(runner, command)(*args))
    except EOFError:  # the trainer is gone
        pass
    finally:
        runner.close()
        conn.close()


class ProcessPhysics(PhysicsBackend):
    """One spawned worker process per task env (the CPU simulator runs one env per process).

    Workers ignore Ctrl-C and SIGTERM (``sb3_memret.common.workers``): the trainer handles them and
    closes its workers. A worker that dies is named with its pid and how it ended
    (``WorkerDiedError``).
    """

    shares_cores = True

    def __init__(self, num_envs: int, task_kwargs: Mapping[str, Any], max_control_steps: int, task: Task | str):
        self.num_envs = num_envs
        context = multiprocessing.get_context(START_METHOD)
        self.conns: list[Connection] = []
        self.processes: list[BaseProcess] = []
        self.closed = False
        # workers ignore SIGTERM, which is how multiprocessing ends daemon processes at exit: close them first
        self._finalizer = weakref.finalize(self, _close_workers, self.conns, self.processes)
        for _ in range(num_envs):
            ours, theirs = context.Pipe()
            process = context.Process(target=_process_worker, args=(theirs, dict(task_kwargs), max_control_steps, task),
                                      daemon=True)
            process.start()
            theirs.close()
            self.conns.append(ours)
            self.processes.append(process)
        try:
            infos = [self._recv(i, "while building its env") for i in range(num_envs)]
        except BaseException:
            self.close()
            raise
        self.env_info = infos[0]

    def _died(self, i: int, doing: str) -> WorkerDiedError:
        return WorkerDiedError(f"physics worker {i} (pid {self.processes[i].pid}) "
                               f"{exit_description(self.processes[i])} {doing}")

    def _send(self, i: int, message: Any) -> None:
        try:
            self.conns[i].send(message)
        except (EOFError, OSError) as err:
            raise self._died(i, "before it could take a command") from err

    def _recv(self, i: int, doing: str = "before it answered") -> Any:
        try:
            return self.conns[i].recv()
        except (EOFError, OSError) as err:
            raise self._died(i, doing) from err

    def _call(self, calls: Mapping[int, tuple[str, tuple]]) -> dict[int, EnvFrame]:
        """Send every env its command, then gather the answers as they arrive."""
        for i, message in calls.items():
            self._send(i, message)
        waiting = {self.conns[i]: i for i in calls}
        frames: dict[int, EnvFrame] = {}
        while waiting:
            for conn in wait(list(waiting)):
                i = waiting.pop(conn)
                frames[i] = self._recv(i)
        return {i: frames[i] for i in calls}

    def reset(self, requests: Sequence[ResetRequest]) -> dict[int, EnvFrame]:
        return self._call({r.env_id: ("reset", (r.seed, dict(r.options))) for r in requests})

    def execute(self, chunks: Mapping[int, np.ndarray]) -> dict[int, EnvFrame]:
        return self._call({i: ("execute", (np.asarray(chunk),)) for i, chunk in chunks.items()})

    def close(self) -> None:
        """Close the workers (``_close_workers``); also done at interpreter exit if nobody called it."""
        self.closed = True
        self._finalizer()


def _close_workers(conns: Sequence[Connection], processes: Sequence[BaseProcess]) -> None:
    """Tell every live worker to close and wait for it; never waits on a reply (after an interrupt some
    are read and some are not). A worker that outstays ``CLOSE_TIMEOUT`` is killed."""
    for conn, process in zip(conns, processes):
        if process.is_alive():
            try:
                conn.send(("close", None))
            except (EOFError, OSError):
                pass
    for process in processes:
        process.join(timeout=CLOSE_TIMEOUT)
        if process.is_alive():  # workers ignore SIGTERM
            process.kill()
            process.join()
    for conn in conns:
        conn.close()


class BatchedSimPhysics(PhysicsBackend):
    """One ManiSkill env with ``num_envs=N`` (GPU simulation: ``sim_backend="gpu"``): every env steps together.

    An env whose chunk is shorter, or whose episode ends inside the chunk, is held still by
    zero actions for the remaining steps; its frame is taken when its own chunk (or episode)
    ended and it is reset before it acts again. Resets are partial (``options["env_idx"]``),
    grouped by identical options.
    """

    def __init__(self, num_envs: int, task_kwargs: Mapping[str, Any], max_control_steps: int, task: Task | str):
        """``task_kwargs`` may name ``sim_backend`` ("gpu" by default; "cpu" holds one env: a dry run)."""
        self.num_envs = num_envs
        self.task = make_task(task)
        if self.task.perceives_every_step:
            raise ValueError(f"task {self.task.name!r} perceives every control step, which the batched simulation "
                             "does not yet do: use --backend process")
        task_kwargs = {"sim_backend": "gpu", **task_kwargs}
        if task_kwargs["sim_backend"] in ("gpu", "physx_cuda"):
            from sb3_memret.physics.devices import check_cuda

            check_cuda()
        self.env = self.task.make_env(max_episode_steps=max_control_steps, num_envs=num_envs, **task_kwargs)
        self.env_info = TaskEnvInfo.of(self.env)
        self.action_dim = int(self.env.action_space.shape[-1])
        self.succeeded = np.zeros(num_envs, dtype=bool)

    def reset(self, requests: Sequence[ResetRequest]) -> dict[int, EnvFrame]:
        import torch

        groups: dict[tuple, list[ResetRequest]] = {}
        for request in requests:
            groups.setdefault(tuple(sorted(request.options.items())), []).append(request)
        frames: dict[int, EnvFrame] = {}
        for options, group in groups.items():
            ids = [r.env_id for r in group]
            idx = torch.as_tensor(ids, dtype=torch.long)
            # ManiSkill draws a partial reset's placements from the torch RNG seeded with the group's first seed
            obs, info = self.env.reset(seed=group[0].seed, options={**dict(options), "env_idx": idx})
            batch = self.task.frames(self.env, obs, info, reset=True)
            for i in ids:
                frames[i] = batch[i]
                self.succeeded[i] = batch[i].success
        return frames

    def execute(self, chunks: Mapping[int, np.ndarray]) -> dict[int, EnvFrame]:
        horizon = max(len(chunk) for chunk in chunks.values())
        actions = np.zeros((horizon, self.num_envs, self.action_dim), dtype=np.float32)
        running = np.zeros(self.num_envs, dtype=bool)
        for i, chunk in chunks.items():
            actions[: len(chunk), i] = chunk
            running[i] = True
        ends = {i: len(chunk) for i, chunk in chunks.items()}
        rewards = np.zeros(self.num_envs)
        frames: dict[int, EnvFrame] = {}
        paused = sensors_pause(self.env)
        for step in range(horizon):
            observed = paused is None or step == horizon - 1 or any(ends[i] == step + 1 for i in chunks)
            with nullcontext() if observed else paused():
                obs, reward, terminated, truncated, info = self.env.step(actions[step])  # ManiSkill moves it to the sim device
            term, trunc = to_numpy(terminated).reshape(-1), to_numpy(truncated).reshape(-1)
            rewards += np.where(running, to_numpy(reward).reshape(-1), 0.0)
            self.succeeded |= running & to_numpy(info["success"]).reshape(-1).astype(bool)
            finished = [i for i in chunks if running[i] and (term[i] or trunc[i] or ends[i] == step + 1)]
            if finished:
                batch = self.task.frames(self.env, obs, info)
                for i in finished:
                    running[i] = False
                    frame = batch[i]
                    frame.success, frame.steps, frame.reward = bool(self.succeeded[i]), step + 1, float(rewards[i])
                    ended = bool(term[i]) or (self.task.ends_at_success and bool(self.succeeded[i]))
                    frame.terminated, frame.truncated = ended, bool(trunc[i]) and not ended
                    frames[i] = frame
            if not running.any():
                break
        return {i: frames[i] for i in chunks}

    def close(self) -> None:
        self.env.close()


__all__ = ["BACKENDS", "BatchedSimPhysics", "InProcessPhysics", "PhysicsBackend", "ProcessPhysics", "ResetRequest",
           "TaskEnvInfo", "TaskRunner"]
