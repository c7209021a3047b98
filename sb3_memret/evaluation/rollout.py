"""Run a frozen controller on a task under a prompt condition (oracle / none / wrong / written) and score it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping, Protocol, Sequence

import numpy as np

from sb3_memret.controllers.base import FrozenController
from sb3_memret.controllers.pacing import replan_interval
from sb3_memret.memory.schema import Key, MemoryType
from sb3_memret.memory.writer import EventCompiler
from sb3_memret.common.obs_trees import stack_obs
from sb3_memret.common.seeds import held_out_seeds
from sb3_memret.physics.backends import TaskRunner
from sb3_memret.controllers.prompts import CONDITIONS, build_prompt, check_fixed_condition
from sb3_memret.tasks import Task, make_task
from sb3_memret.tasks.base import RENDER_BACKENDS, EnvFrame, Episode, check_render_backend


@dataclass(frozen=True)
class EpisodeResult:
    group: str  # the group success is reported by (``Episode.group``: the drawer's layer, a cue's colour)
    seed: int
    success: bool
    steps: int  # control steps until success (at the end of the chunk it succeeded in), or the episode's length


def task_env_kwargs(controller: FrozenController, render_backend: str, task: Task) -> dict[str, str]:
    """The obs mode and render backend ``controller`` needs on ``task``: camera images ("rgb") for an image
    controller, which therefore cannot run without a render backend."""
    check_render_backend(render_backend)
    try:
        return task.env_kwargs(controller.spec.needs_images, render_backend)
    except ValueError as err:
        raise ValueError(f"{type(controller).__name__} {err}") from None


class FactSchedule(Protocol):
    """The facts an episode's prompt carries at each of its decisions (``play_task_episodes``). A schedule that
    subclasses it inherits ``observe``'s no-op; one that matches it only structurally defines ``observe`` too."""

    def start(self, frame: EnvFrame, episode: Episode) -> None:
        """A new episode begins, at ``frame``."""

    def facts(self, decision: int) -> Sequence[str]:
        """The facts appended to the instruction at ``decision`` (0, 1, ...)."""

    def observe(self, frame: EnvFrame) -> None:
        """The frame an executed chunk left (its per-step percepts included), before the next decision."""


@dataclass
class ConditionFacts(FactSchedule):
    """A fixed prompt condition's facts, the same at every decision: oracle, wrong, or none (a task whose facts
    follow the robot's work words them from the latest frame, ``Task.facts_now``); then, for a task with progress as
    memory, what the robot has done so far, from the simulator (``Task.progress_facts``)."""

    task: Task
    condition: str
    _episode: Episode | None = None
    _frame: EnvFrame | None = None
    _progress: list[str] = field(default_factory=list)
    t: int = 0  # control steps into the episode: a task's facts may carry a time (``Task.facts_at``)

    def __post_init__(self) -> None:
        check_fixed_condition(self.condition)

    def start(self, frame: EnvFrame, episode: Episode) -> None:
        self._episode, self._frame, self.t = episode, frame, 0
        self._progress = self.task.progress_facts(frame)

    def observe(self, frame: EnvFrame) -> None:
        self.t += frame.steps
        self._frame = frame
        self._progress = self.task.progress_facts(frame)

    def facts(self, decision: int) -> Sequence[str]:
        facts = [] if self.condition == "none" else self.task.facts_now(self.condition, self._episode, self._frame,
                                                                        self.t)
        return [*facts, *self._progress]


class WrittenFacts(FactSchedule):
    """The written condition: the facts the task's writer has written so far in the episode, no retriever, no decoys.

    The writer (``Task.writer``) reads every frame the physics returns, the reset frame's and each chunk's, per-step
    percepts included, and its predicates are compiled as the decision env compiles them (``EventCompiler``: a fact
    is written when a predicate changes and replaces the fact with its key in place, as in the bank); the prompt
    carries them all, in the order first written, with no bank limit. So a writer that misreads or misses what must
    be remembered fails here where ``oracle`` succeeds. The drawer's writer reads the target's drawer from the
    simulator's state (its seeded memory, ``memory_source: seeded``): there it checks the facts' wording and their
    updates as the episode goes (the cube taken out, held), not perception.
    """

    def __init__(self, task: Task):
        self.task = task
        self.writer = task.writer()  # one writer for the schedule's episodes, as one env's in the decision env
        self.compiler = EventCompiler(None, self.writer.relations, task.wordings)
        self._facts: dict[Key, str] = {}
        self.t = 0  # control steps into the episode

    def start(self, frame: EnvFrame, episode: Episode) -> None:
        self.compiler.reset()
        self._facts, self.t = {}, 0
        self.observe(frame)

    def observe(self, frame: EnvFrame) -> None:
        for step, predicates in self.writer.read(frame):
            for entry in self.compiler.update(predicates, self.t + step):
                self._facts[entry.key] = entry.text
        self.t += frame.steps

    def facts(self, decision: int) -> Sequence[str]:
        return list(self._facts.values())

    def wrote(self, keys: Iterable[Key]) -> bool:
        """Whether the writer has written a fact under every one of ``keys`` this episode (whatever its value)."""
        return all(key in self._facts for key in keys)

    def facts_of_type(self, mtype: MemoryType) -> list[str]:
        """The facts of type ``mtype`` written so far (TASK_PROGRESS: what the robot has done)."""
        return [text for key, text in self._facts.items() if key[0] == mtype]


def condition_schedule(task: Task, condition: str) -> FactSchedule:
    """The facts ``condition`` gives each decision of ``task``: fixed (oracle, none, wrong) or the writer's (written)."""
    if condition not in CONDITIONS:
        raise ValueError(f"unknown condition {condition!r}; expected one of {list(CONDITIONS)}")
    return WrittenFacts(task) if condition == "written" else ConditionFacts(task, condition)


def play_episode(
    runner: TaskRunner,
    controller: FrozenController,
    seed: int,
    schedule: FactSchedule | str,
    replan_every: int | None = None,
    reset_options: Mapping[str, Any] | None = None,
    check_prompt: bool = True,
) -> EpisodeResult:
    """One episode of ``runner``'s task from ``seed`` (its env reset with ``reset_options``, e.g. the drawer's
    ``target_layer``): the controller replans every ``replan_every`` control steps (None: the task's) with the
    instruction and the facts ``schedule`` gives that decision, and ``schedule`` observes every frame; a ``str``
    schedule is one prompt text for every decision, as given (with ``check_prompt=False``, wording the controller was
    never trained on: the ablations'). Success is the task's (once per episode). ``check_prompt=False`` waives the
    prompt contract (``FrozenController.act``)."""
    replan_every = replan_interval(runner.task, replan_every, controller)
    return _play(runner, controller, seed, schedule, replan_every, reset_options, check_prompt)


def _play(runner: TaskRunner, controller: FrozenController, seed: int, schedule: FactSchedule | str,
          replan_every: int, reset_options: Mapping[str, Any] | None, check_prompt: bool) -> EpisodeResult:
    """``play_episode`` with ``replan_every`` already resolved."""
    task = runner.task
    frame = runner.reset(seed, reset_options or {})
    episode = task.episode(frame)
    literal = schedule if isinstance(schedule, str) else None
    if literal is None:
        schedule.start(frame, episode)
    controller.reset([seed])
    decision, steps, success_steps = 0, 0, 0 if frame.success else None
    while not (frame.terminated or frame.truncated):
        prompt = literal if literal is not None else build_prompt(task.instruction(episode), schedule.facts(decision),
                                                                  controller.spec.prompt_template)
        frame = runner.execute(controller.act(stack_obs([frame.obs]), [prompt], check_prompt)[0][:replan_every])
        if literal is None:
            schedule.observe(frame)
        decision, steps = decision + 1, steps + frame.steps
        if frame.success and success_steps is None:
            success_steps = steps  # at the end of the chunk it succeeded in
    return EpisodeResult(episode.group, seed, frame.success, steps if success_steps is None else success_steps)


def play_task_episodes(
    controller: FrozenController,
    task: Task,
    seeds: Iterable[int],
    schedule: FactSchedule,
    replan_every: int | None = None,
    on_episode: Callable[[EpisodeResult], None] | None = None,
    render_backend: str | None = None,
    reset_options: Mapping[str, Any] | None = None,
) -> list[EpisodeResult]:
    """One episode of ``task`` per seed (``play_episode``), in one env of the task made for ``controller``."""
    replan_every = replan_interval(task, replan_every, controller)
    runner = TaskRunner(task_env_kwargs(controller, render_backend or task.default_render_backend, task),
                        task.max_control_steps, task)
    results = []
    try:
        controller.check_env(runner.info())
        for episode_seed in seeds:
            results.append(_play(runner, controller, episode_seed, schedule, replan_every, reset_options, True))
            if on_episode is not None:
                on_episode(results[-1])
    finally:
        runner.close()
    return results


def evaluate_task_condition(
    controller: FrozenController,
    condition: str,
    task: Task | str,
    episodes: int,
    seed: int = 0,
    replan_every: int | None = None,
    on_episode: Callable[[EpisodeResult], None] | None = None,
    render_backend: str | None = None,
    reset_options: Mapping[str, Any] | None = None,
    held_out: str | None = "development",
) -> list[EpisodeResult]:
    """``episodes`` episodes of ``task`` at its ``held_out`` seeds where it has them ("development": MIKASA's
    5000 + i, for every choice; "evaluation": its protocol's 4242424242 + i, the test set, for the final figure only),
    else (or with ``held_out=None``) at seed..seed+episodes-1, each prompted by ``condition``: the
    task's instruction with its oracle facts, with none, with its wrong facts, or with the facts its writer has
    written so far (``WrittenFacts``); the controller replans every ``replan_every`` steps (None: the task's).
    Success is the task's (once per episode)."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    task = make_task(task)
    schedule = condition_schedule(task, condition)
    seeds = (held_out_seeds(task, held_out, episodes) if held_out is not None else None) or range(seed, seed + episodes)
    return play_task_episodes(controller, task, seeds, schedule, replan_every, on_episode, render_backend,
                              reset_options)


def summarize(results: Iterable[EpisodeResult]) -> dict:
    """Success rate and median steps-to-success per group and overall."""
    results = list(results)
    summary: dict = {"success": {}, "median_steps_to_success": {}, "episodes": {}}
    groups = {str(key): [r for r in results if r.group == key] for key in sorted({r.group for r in results}, key=str)}
    groups["overall"] = results
    for key, group in groups.items():
        wins = [r.steps for r in group if r.success]
        summary["episodes"][key] = len(group)
        summary["success"][key] = len(wins) / len(group) if group else float("nan")
        summary["median_steps_to_success"][key] = float(np.median(wins)) if wins else None
    return summary


__all__ = ["ConditionFacts", "EpisodeResult", "FactSchedule", "RENDER_BACKENDS", "WrittenFacts",
           "condition_schedule", "evaluate_task_condition", "play_episode", "play_task_episodes",
           "summarize", "task_env_kwargs"]
