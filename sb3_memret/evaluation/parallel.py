"""Controller episodes over many task envs and ONE controller.

``run_jobs`` plays episode jobs (a prompt, a seed and reset options, a replan interval) of one task in ``n_envs``
envs placed by a physics backend (``sb3_memret.physics``: worker processes, a batched GPU
simulation or Ray actors) while one controller in this process serves them all: one ``act``
call per round for every env. Results come back in job order whatever order they finish in.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers.base import FrozenController
from sb3_memret.controllers.pacing import replan_interval
from sb3_memret.tasks.base import EnvFrame
from sb3_memret.physics.backends import ResetRequest
from sb3_memret.physics import make_physics
from sb3_memret.common.obs_trees import stack_obs
from sb3_memret.controllers.prompts import parse_prompt
from sb3_memret.evaluation.rollout import EpisodeResult, task_env_kwargs
from sb3_memret.tasks import Task, make_task
from sb3_memret.common.workers import torch_threads


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to play: the prompt, the seed and the task's reset options (the drawer's ``target_layer``), the
    replan interval (None: the task's)."""

    prompt: str
    seed: int
    reset_options: Mapping[str, Any] = field(default_factory=dict)
    replan_every: int | None = None
    check_prompt: bool = True  # False only where an ablation measures untrained wording

    def __hash__(self) -> int:  # the options are a mapping: hashed by their items
        return hash((self.prompt, self.seed, tuple(sorted(self.reset_options.items())), self.replan_every,
                     self.check_prompt))


def run_jobs(
    controller: str | FrozenController,
    jobs: Sequence[EpisodeJob],
    task: Task | str,
    n_envs: int = 1,
    render_backend: str = "none",
    on_result: Callable[[EpisodeJob, EpisodeResult], None] | None = None,
    backend: str = "auto",
    ray_address: str | None = None,
) -> list[EpisodeResult]:
    """Play ``jobs`` in ``n_envs`` envs of ``task`` with one controller; results in job order.

    Every round the controller acts once for all envs (an env with no job left repeats its last
    observation and its chunk is dropped); each env executes the first ``replan_every`` actions
    of its job's chunk. Each episode starts as ``rollout.play_episode`` starts it (reset with the job's
    seed and options, the controller's env reset with the seed), so it plays the same whatever
    ``n_envs`` and the backend. Prompts are checked against the controller's template before
    anything starts, except those of jobs that waive the check.
    """
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    if not jobs:
        return []
    task = make_task(task)
    controller = make_controller(controller, task) if isinstance(controller, str) else controller
    executed_steps = [replan_interval(task, job.replan_every, controller) for job in jobs]
    for job in jobs:
        if job.check_prompt:
            parse_prompt(job.prompt, controller.spec.prompt_template)
    n = min(n_envs, len(jobs))
    physics = make_physics(backend, n, task_env_kwargs(controller, render_backend, task), task.max_control_steps,
                           ray_address, task=task)
    results: list[EpisodeResult | None] = [None] * len(jobs)
    try:
        controller.check_env(physics.env_info)
        queue = deque(range(len(jobs)))
        playing: dict[int, int] = {}  # env -> index of the job it plays
        latest = [0] * n  # env -> index of the job it last started (an idle env repeats its prompt)
        steps = [0] * n
        groups = [""] * n  # env -> the group of the episode it plays (``Episode.group``)
        frames: dict[int, EnvFrame] = {}

        def start(envs: list[int]) -> None:
            starting = {i: queue.popleft() for i in envs if queue}
            if not starting:
                return
            requests = [ResetRequest(i, jobs[j].seed, jobs[j].reset_options) for i, j in starting.items()]
            first = not frames
            frames.update(physics.reset(requests))
            seeds = [jobs[j].seed for j in starting.values()]
            if first:  # the first start fills every env: the controller's batch
                controller.reset(seeds)
            else:
                controller.reset_envs(list(starting), seeds)
            playing.update(starting)
            for i, j in starting.items():
                steps[i], latest[i], groups[i] = 0, j, task.episode(frames[i]).group

        start(list(range(n)))
        while playing:
            last = {i: j for i, j in playing.items()}
            prompts = [jobs[j].prompt for j in latest]
            check = all(jobs[j].check_prompt for j in latest)
            with torch_threads(1 if physics.shares_cores else None):
                chunks = controller.act(stack_obs([frames[i].obs for i in range(n)]), prompts, check)
            executed = physics.execute({i: chunks[i, : executed_steps[j]] for i, j in last.items()})
            ended = []
            for i, frame in executed.items():
                frames[i] = frame
                steps[i] += frame.steps
                if frame.terminated or frame.truncated:
                    j = playing.pop(i)
                    results[j] = EpisodeResult(groups[i], jobs[j].seed, frame.success, steps[i])
                    if on_result is not None:
                        on_result(jobs[j], results[j])
                    ended.append(i)
            start(ended)
    finally:
        physics.close()
    return results  # type: ignore[return-value]


__all__ = ["EpisodeJob", "run_jobs"]
