"""A task's expert demonstrations as a LeRobotDataset (v3.0), for any task with a demonstration layout.

The drawer has its own recorder (``demos.py``: layers chosen per episode, DAgger rounds, object sets);
this one serves every other task through the ``Task`` interface alone. Each episode starts at its seed
(MIKASA's cue is drawn from it), then its prompt is drawn by ``PromptMix``: the bare instruction, the
instruction with the task's true facts (``oracle_facts``: ``the cue cube was red.``), or with facts
naming something else (``wrong_facts``), which the expert follows as a controller trained on them would.
Per frame: ``Task.demo_frame`` (state, cameras with a renderer), the expert's action as label, the
exact prompt as ``task``; with ``frames="decisions"`` only the steps a controller acts at, each with its
chunk of labels (as the drawer's recorder), the cameras rendering only there. A share of episodes runs with
Gaussian noise on the arm (labels stay clean). A task whose writer writes progress (TASK_PROGRESS facts: ``the red cube was touched.``)
has it run along: each decision's prompt carries, after the kind's facts, the progress written so far, so the
prompt changes as the episode goes and every frame keeps the prompt it was acted on. With a learner
(``learner=``, a controller spec) it is a DAgger round: the learner acts
on the prompt while the expert labels the states it reaches, as the drawer's recorder does.
Episodes are written as they finish; an interrupted run keeps every episode saved so far.
"""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers.base import FrozenController, as_numpy
from sb3_memret.controllers.observation import ACTION_CHUNK_KEY, ACTION_KEY, CHUNK_PAD_KEY, TASK_KEY, chunk_features
from sb3_memret.memory.schema import MemoryType
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.evaluation.rollout import WrittenFacts
from sb3_memret.physics.sensor_gate import sensors_pause
from sb3_memret.stage1.demos import DemoDatasetWriter, PromptMix, check_frames, label_chunks
from sb3_memret.tasks import Task, make_task
from sb3_memret.tasks.base import check_render_backend

PROMPT_KINDS = ("bare", "matching", "mismatched")


@dataclass(frozen=True)
class TaskDemoEpisode:
    """One demonstration to record: the task seed, which prompt it gets, and the action noise on the arm."""

    seed: int
    prompt_kind: str
    noise: float = 0.0


@dataclass
class TaskEpisodeFrames:
    """A recorded episode: its frames in the task's layout, the expert's labels, and how it went."""

    episode: TaskDemoEpisode
    prompt: str  # the first decision's
    group: str
    frames: list[dict[str, np.ndarray]]  # the kept frames (every step, or the decision steps)
    prompts: list[str]  # the prompt each kept frame was acted on (one for all, without progress facts)
    actions: np.ndarray  # (T, action_dim): the expert's label at every control step
    success: bool
    frame_steps: np.ndarray  # (F,) the control step of each kept frame
    learner_acted: bool = False  # a DAgger episode: the learner acted, the expert only labelled


def plan_task_episodes(n: int, seed: int = 0, noise: float = 0.0, noisy_fraction: float = 0.5,
                       mix: PromptMix | None = None) -> list[TaskDemoEpisode]:
    """``n`` episodes at task seeds ``seed..seed+n-1``, prompt kinds drawn by ``mix``, ``noisy_fraction``
    of them with arm noise ``noise``."""
    if n < 1:
        raise ValueError(f"episodes must be >= 1, got {n}")
    if noise < 0 or not 0 <= noisy_fraction <= 1:
        raise ValueError(f"noise must be >= 0 and noisy_fraction in [0, 1], got {noise}, {noisy_fraction}")
    mix = mix or PromptMix()
    rng = np.random.default_rng(seed)
    kinds = rng.choice(len(PROMPT_KINDS), size=n, p=[mix.bare, mix.matching, mix.mismatched])
    noisy = rng.random(n) < noisy_fraction
    return [TaskDemoEpisode(seed + k, PROMPT_KINDS[kinds[k]], noise if noisy[k] else 0.0) for k in range(n)]


class TaskRecorder:
    """A task env and the task's expert, recording episodes one after another; with a learner (a controller
    spec or instance) the learner acts and the expert labels."""

    def __init__(self, task: Task | str, render_backend: str, replan_every: int | None = None,
                 frames: str = "every", learner: str | FrozenController | None = None, max_steps: int | None = None):
        self.task = make_task(task)
        if max_steps is not None and max_steps < 1:
            raise ValueError(f"max_steps must be >= 1 (or None: the task's own limit), got {max_steps}")
        self.decisions_only = check_frames(frames) == "decisions"
        self.with_images = check_render_backend(render_backend) != "none"
        self.expert = self.task.expert()
        replan_every = self.task.replan_interval(replan_every, self.expert.spec.chunk_len, "the expert's")
        self.task.demo_features(self.with_images)  # a task without a layout refuses before any env is made
        self.env = self.task.make_env(**self.task.env_kwargs(self.with_images, render_backend),
                                      max_episode_steps=max_steps)
        self.expert.check_env(self.env)
        self.learner = make_controller(learner, self.task) if isinstance(learner, str) else learner
        if self.learner is not None:
            self.task.replan_interval(replan_every, self.learner.spec.chunk_len, "the learner's")
            self.learner.check_env(self.env)
        self.replan_every = replan_every
        writes_progress = any(mtype == MemoryType.TASK_PROGRESS for mtype, _ in self.task.writer().relations.values())
        self.progress = WrittenFacts(self.task) if writes_progress else None
        # keeping decision frames only, a step inside a chunk leaves images nobody reads (unless the progress writer
        # perceives every step): its cameras pause, and the outcome is the same (physics never reads the renderer)
        unread = self.with_images and self.decisions_only and not (self.progress is not None
                                                                   and self.task.perceives_every_step)
        self.pause = sensors_pause(self.env) if unread else None

    def record(self, episode: TaskDemoEpisode) -> TaskEpisodeFrames:
        """Play one episode, the expert (or the learner) acting on each decision's prompt (the episode's kind of
        facts, then any progress written so far) and the expert labelling every frame."""
        rng = np.random.default_rng(episode.seed)
        obs, info = self.env.reset(seed=episode.seed)
        first = self.task.frames(self.env, obs, info, reset=True)[0]
        truth = self.task.episode(first)
        facts = {"bare": [], "matching": self.task.oracle_facts(truth),
                 "mismatched": self.task.wrong_facts(truth)}[episode.prompt_kind]
        if self.progress is not None:
            first.percepts = [self.task.perceive(self.env, obs)] if self.task.perceives_every_step else []
            self.progress.start(first, truth)
        self.expert.reset([episode.seed])
        if self.learner is not None:
            self.learner.reset([episode.seed])
        frames, prompts, kept, actions, success, done = [], [], [], [], False, False
        while not done:
            done_so_far = self.progress.facts_of_type(MemoryType.TASK_PROGRESS) if self.progress is not None else []
            prompt = build_prompt(self.task.instruction(truth), [*facts, *done_so_far],
                                  self.expert.spec.prompt_template)
            labels = self.expert.act(obs, [prompt])[0][: self.replan_every]
            executed = labels if self.learner is None else self.learner.act(obs, [prompt])[0][: self.replan_every]
            percepts = []
            for i, (label, action) in enumerate(zip(labels, executed)):
                if i == 0 or not self.decisions_only:
                    kept.append(len(actions))
                    frames.append(self.task.demo_frame(obs, self.with_images))
                    prompts.append(prompt)
                actions.append(label)
                action = np.array(action, np.float32)
                if episode.noise:
                    action[:6] = np.clip(action[:6] + rng.normal(0.0, episode.noise, 6), -1.0, 1.0)
                chunk_ends = i == len(labels) - 1  # its observation is the next decision's
                with self.pause() if self.pause is not None and not chunk_ends else nullcontext():
                    obs, _, terminated, truncated, info = self.env.step(action[None])
                if self.progress is not None and self.task.perceives_every_step:
                    percepts.append(self.task.perceive(self.env, obs))
                success = success or bool(np.any(as_numpy(info["success"])))  # MIKASA counts success once
                done = bool(np.any(as_numpy(terminated)) or np.any(as_numpy(truncated))
                            or (self.task.ends_at_success and success))  # as the decision env and the benchmark
                if done:
                    break
            if self.progress is not None and not done:  # the writer reads the chunk's frame, as the decision env's
                frame = self.task.frames(self.env, obs, info)[0]
                frame.steps, frame.percepts = i + 1, percepts
                self.progress.observe(frame)
        return TaskEpisodeFrames(episode, prompts[0], truth.group, frames, prompts, np.asarray(actions, np.float32),
                                 success, np.asarray(kept), self.learner is not None)


_recorder: TaskRecorder | None = None


def _init_recorder(task: Task | str, render_backend: str, replan_every: int, frames: str = "every",
                   learner: str | None = None, max_steps: int | None = None, in_worker: bool = True) -> None:
    global _recorder
    if in_worker:
        from sb3_memret.common.workers import init_pool_worker

        init_pool_worker()
    _recorder = TaskRecorder(task, render_backend, replan_every, frames, learner, max_steps)


def _record(episode: TaskDemoEpisode) -> TaskEpisodeFrames:
    assert _recorder is not None, "recorder used before its initializer ran"
    return _recorder.record(episode)


def record_task_demos(
    out: str | Path,
    task: Task | str,
    episodes: Sequence[TaskDemoEpisode],
    render_backend: str = "cpu",
    n_workers: int = 1,
    replan_every: int | None = None,
    on_episode: Callable[[TaskEpisodeFrames], None] | None = None,
    frames: str = "every",
    learner: str | None = None,
    max_steps: int | None = None,
) -> Path:
    """Record ``episodes`` of ``task``'s expert into a new LeRobotDataset at ``out`` and return its folder;
    ``frames`` (``every`` or ``decisions``) says which control steps it keeps; ``learner`` (a controller spec)
    makes it a DAgger round, the learner acting and the expert labelling; ``max_steps`` ends each episode after
    that many control steps (None: the task's own limit)."""
    from sb3_memret.common.workers import map_in_workers

    the_task = make_task(task)
    if learner is not None and n_workers > 1:
        make_controller(learner, the_task)  # a bad spec fails here, before any worker starts (one worker: in-process)
    with_images = check_render_backend(render_backend) != "none"
    features = the_task.demo_features(with_images)
    chunk_len = the_task.expert().spec.chunk_len if check_frames(frames) == "decisions" else None
    robot = the_task.env_kwargs(with_images, render_backend).get("robot_uids")  # None: the env's own, unrecorded
    writer = DemoDatasetWriter(out, {**features, **(chunk_features(chunk_len) if chunk_len else {})}, robot)

    def save(_: TaskDemoEpisode, recorded: TaskEpisodeFrames) -> None:
        chunks, pads = label_chunks(recorded.actions, recorded.frame_steps, chunk_len) if chunk_len else (None, None)
        writer.add_episode(
            ({**frame, ACTION_KEY: recorded.actions[step], TASK_KEY: recorded.prompts[i],
              **({ACTION_CHUNK_KEY: chunks[i], CHUNK_PAD_KEY: pads[i]} if chunk_len else {})}
             for i, (frame, step) in enumerate(zip(recorded.frames, recorded.frame_steps))),
            {**asdict(recorded.episode), "task": the_task.name, "prompt": recorded.prompt, "group": recorded.group,
             "frames": len(recorded.frames), "steps": len(recorded.actions), "success": recorded.success,
             "learner": learner})
        if on_episode is not None:
            on_episode(recorded)

    global _recorder
    try:
        map_in_workers(_init_recorder, (task, render_backend, replan_every, frames, learner, max_steps), _record,
                       list(episodes), n_workers, save)
    finally:
        writer.close()
        if _recorder is not None:
            _recorder.env.close()
            _recorder = None
    return Path(out)


__all__ = ["PROMPT_KINDS", "TaskDemoEpisode", "TaskEpisodeFrames", "TaskRecorder", "plan_task_episodes",
           "record_task_demos"]
