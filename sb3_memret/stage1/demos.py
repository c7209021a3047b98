"""Expert demonstrations of any task as a LeRobotDataset (v3.0), written with lerobot's own recording API.

Which episodes are recorded is the task's plan (``Task.plan_demos``, ``sb3_memret.tasks.demos``): each episode's
seed, its prompt kind (the bare instruction, the task's true facts such as ``the cue cube was red.``, or facts naming
something else, which the expert follows as a controller trained on them would), its arm noise and the reset options
that choose its group (the drawer's layers). Per frame: ``Task.demo_frame`` (the state a controller may see, and with
a renderer the cameras under the keys π0.5-LIBERO finetuning reads, resized to ``image_size``), ``action`` (the
expert's label for that step) and ``task`` (the exact prompt the frame was acted on). ``frames="every"`` keeps every
control step (lerobot builds action chunks from consecutive frames, as π0.5's finetuning reads them);
``frames="decisions"`` keeps only the steps a controller acts at, each with the expert's labels for its next
``chunk_len`` steps as ``action_chunk`` (``action_chunk_is_pad`` past the episode's end), and renders the cameras
only there: a camera frame costs ~55 ms here, a control step ~4 ms.

States off the expert's path: a share of the episodes executes the expert's actions with Gaussian noise on the arm
(the labels stay the expert's clean actions), and DAgger rounds (``learner=``) let a learned controller act while
the expert, which can label any state, shadows it and supplies every label. A task whose writer writes progress
(TASK_PROGRESS facts: ``the red cube was touched.``) has it run along: each decision's prompt carries, after the
kind's facts, the progress written so far. A ``recalled`` episode runs the writer too: its prompts carry a decoy (the
task's ``seed_memories``) until the writer has read every true fact, then the true facts, as the recall condition's
memory gives them; the expert acts and labels on the prompt without the decoy (a fact about another thing changes
nothing it should do), so a controller trained on it learns to act as if told nothing until the fact is known. An
episode ends at the task's end, at success where the task ends there, or once the expert has given up for
``idle_stop`` steps (``Task.expert_gave_up``: the drawer's empty drawer).
Episodes are written as they finish, with a line each in ``sb3_memret_episodes.jsonl`` saying how it was played; an
interrupted run finalises the dataset with every episode saved so far.
"""

from __future__ import annotations

import json
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers.base import FrozenController, as_numpy
from sb3_memret.controllers.observation import (ACTION_CHUNK_KEY, ACTION_KEY, CHUNK_PAD_KEY, TASK_KEY, chunk_features,
                                                resize_images)
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.evaluation.rollout import WrittenFacts
from sb3_memret.memory.schema import MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.physics.grasp_memo import install_grasp_memo
from sb3_memret.physics.sensor_gate import sensors_pause
from sb3_memret.tasks import Task, make_task
from sb3_memret.tasks.base import check_render_backend
from sb3_memret.tasks.demos import DemoEpisode

FPS = 20  # the pd_ee_delta_pose control frequency of the drawer's and MIKASA's envs
EPISODES_FILE = "sb3_memret_episodes.jsonl"  # one line per saved episode: how it was played
FRAME_CHOICES = ("every", "decisions")  # which control steps a dataset keeps
IDLE_STOP = 16  # control steps an expert that gave up holds still before its recording ends


def check_frames(frames: str) -> str:
    if frames not in FRAME_CHOICES:
        raise ValueError(f"unknown frames {frames!r}; expected one of {list(FRAME_CHOICES)}")
    return frames


def label_chunks(actions: np.ndarray, steps: np.ndarray, chunk_len: int) -> tuple[np.ndarray, np.ndarray]:
    """``actions[s : s + chunk_len]`` for each step ``s``, the last label repeated past the end, and its pad mask."""
    raw = np.asarray(steps)[:, None] + np.arange(chunk_len)[None, :]
    return actions[np.minimum(raw, len(actions) - 1)], raw > len(actions) - 1


def image_features(features: dict[str, dict[str, Any]]) -> list[str]:
    """The camera features of a demonstration layout."""
    return [key for key, spec in features.items() if spec["dtype"] == "image"]


def sized_features(task: Task, with_images: bool, image_size: int | None) -> dict[str, dict[str, Any]]:
    """``task``'s demonstration layout with its cameras at ``image_size`` (None: as they render); refused above the
    rendered size or below 16."""
    features = task.demo_features(with_images)
    for key in image_features(features) if image_size is not None else ():
        native = features[key]["shape"][0]
        if not 16 <= image_size <= native:
            raise ValueError(f"image_size must be in [16, {native}] (task {task.name!r}'s cameras render {native}), "
                             f"got {image_size}")
        features[key] = {**features[key], "shape": (image_size, image_size, 3)}
    return features


@dataclass
class EpisodeFrames:
    """A recorded episode: its frames in the task's layout, the expert's labels, and how it went."""

    episode: DemoEpisode
    prompt: str  # the first decision's
    group: str
    frames: list[dict[str, np.ndarray]]  # the kept frames (every step, or the decision steps)
    prompts: list[str]  # the prompt each kept frame was acted on (one for all, without progress facts)
    actions: np.ndarray  # (T, action_dim): the expert's label at every control step
    success: bool
    frame_steps: np.ndarray  # (F,) the control step of each kept frame
    learner_acted: bool = False  # a DAgger episode: the learner acted, the expert only labelled

    def chunks(self, chunk_len: int) -> tuple[np.ndarray, np.ndarray]:
        """Each kept frame's labels for its next ``chunk_len`` steps (F, chunk_len, action_dim) and the pad mask past
        the episode's end (F, chunk_len)."""
        return label_chunks(self.actions, self.frame_steps, chunk_len)


class DemoRecorder:
    """A task env and the task's expert, recording episodes one after another; with a learner (a controller
    spec or instance) the learner acts and the expert labels."""

    def __init__(self, task: Task | str, render_backend: str, replan_every: int | None = None,
                 frames: str = "every", learner: str | FrozenController | None = None, max_steps: int | None = None,
                 image_size: int | None = None, idle_stop: int = IDLE_STOP):
        self.task = make_task(task)
        if max_steps is not None and max_steps < 1:
            raise ValueError(f"max_steps must be >= 1 (or None: the task's own limit), got {max_steps}")
        if idle_stop < 1:
            raise ValueError(f"idle_stop must be >= 1, got {idle_stop}")
        self.decisions_only = check_frames(frames) == "decisions"
        self.with_images = check_render_backend(render_backend) != "none"
        self.expert = self.task.expert()
        replan_every = self.task.replan_interval(replan_every, self.expert.spec.chunk_len, "the expert's")
        features = sized_features(self.task, self.with_images, image_size)  # a task without a layout refuses here
        self.resized = {key: features[key]["shape"][0] for key in image_features(features)} if image_size else {}
        install_grasp_memo()  # repeated grasp checks answered once per physics step (the same answers, faster)
        self.env = self.task.make_env(**self.task.env_kwargs(self.with_images, render_backend),
                                      max_episode_steps=max_steps)
        self.expert.check_env(self.env)
        self.learner = make_controller(learner, self.task) if isinstance(learner, str) else learner
        if self.learner is not None:
            self.task.replan_interval(replan_every, self.learner.spec.chunk_len, "the learner's")
            self.learner.check_env(self.env)
        self.replan_every, self.idle_stop = replan_every, idle_stop
        self.writes_progress = any(mtype == MemoryType.TASK_PROGRESS
                                   for mtype, _ in self.task.writer().relations.values())
        self.written = WrittenFacts(self.task)  # the writer, run along where an episode's prompts need what it reads
        # keeping decision frames only, a step inside a chunk leaves images nobody reads (unless a writer that
        # perceives every step runs along): its cameras pause, and the outcome is the same (physics never reads them)
        self.pause = sensors_pause(self.env) if self.with_images and self.decisions_only else None

    def frame(self, obs: Any) -> dict[str, np.ndarray]:
        """One kept frame in the dataset's layout, its cameras resized."""
        frame = self.task.demo_frame(obs, self.with_images)
        for key, size in self.resized.items():
            frame[key] = resize_images(frame[key][None], size)[0]
        return frame

    def facts(self, episode: DemoEpisode, truth: Any, t: int) -> list[str]:
        """The facts ``episode``'s prompt carries ``t`` control steps in: the plan's, or the task's for its prompt
        kind (``Task.facts_at``; a recalled prompt's are the true ones, once the writer has read them)."""
        if episode.facts is not None:
            return list(episode.facts)
        kinds = {"bare": None, "matching": "oracle", "mismatched": "wrong", "recalled": "oracle"}
        condition = kinds[episode.prompt_kind]
        return [] if condition is None else self.task.facts_at(condition, truth, t)

    def _draw_decoy(self, frame: Any, truth: Any, rng: np.random.Generator) -> str | None:
        """One fact about another thing, as the task seeds a recall memory's bank with them (None: it seeds none)."""
        decoys = self.task.seed_memories(frame, truth, rng, SeedingConfig(location_decoys=1, holding_decoys=0),
                                         facts=False)
        return decoys[0].text if decoys else None

    def record(self, episode: DemoEpisode) -> EpisodeFrames:
        """Play one episode, the expert (or the learner) acting on each decision's prompt (the episode's facts, then
        any progress written so far) and the expert labelling every frame."""
        rng = np.random.default_rng(episode.seed)
        obs, info = self.env.reset(seed=episode.seed, options=dict(episode.reset_options))
        first = self.task.frames(self.env, obs, info, reset=True)[0]
        truth = self.task.episode(first)
        recalled = episode.prompt_kind == "recalled"
        reads = self.writes_progress or recalled  # the writer runs along
        perceives = reads and self.task.perceives_every_step
        if reads:
            first.percepts = [self.task.perceive(self.env, obs)] if perceives else []
            self.written.start(first, truth)
        decoy = self._draw_decoy(first, truth, rng) if recalled else None
        self.expert.reset([episode.seed])
        if self.learner is not None:
            self.learner.reset([episode.seed])
        frames, prompts, kept, actions, success, done, idle = [], [], [], [], False, False, 0
        while not done:
            done_so_far = self.written.facts_of_type(MemoryType.TASK_PROGRESS) if self.writes_progress else []
            # a recalled episode waits for the writer: told nothing until then, with its decoy shown
            waiting = recalled and not self.written.wrote(key for key, _ in truth.true_facts)
            facts = [*([] if waiting else self.facts(episode, truth, len(actions))), *done_so_far]
            prompt = build_prompt(self.task.instruction(truth), facts, self.expert.spec.prompt_template)
            shown = build_prompt(self.task.instruction(truth), [decoy, *facts], self.expert.spec.prompt_template) \
                if waiting and decoy is not None else prompt
            labels = self.expert.act(obs, [prompt])[0][: self.replan_every]
            executed = labels if self.learner is None else self.learner.act(obs, [shown])[0][: self.replan_every]
            percepts = []
            for i, (label, action) in enumerate(zip(labels, executed)):
                if i == 0 or not self.decisions_only:
                    kept.append(len(actions))
                    frames.append(self.frame(obs))
                    prompts.append(shown)
                actions.append(label)
                action = np.array(action, np.float32)
                if episode.noise:
                    action[:6] = np.clip(action[:6] + rng.normal(0.0, episode.noise, 6), -1.0, 1.0)
                chunk_ends = i == len(labels) - 1  # its observation is the next decision's
                with self.pause() if self.pause is not None and not (chunk_ends or perceives) else nullcontext():
                    obs, _, terminated, truncated, info = self.env.step(action[None])
                if perceives:
                    percepts.append(self.task.perceive(self.env, obs))
                success = success or bool(np.any(as_numpy(info["success"])))  # MIKASA counts success once
                idle = idle + 1 if self.task.expert_gave_up(self.expert) else 0
                done = bool(np.any(as_numpy(terminated)) or np.any(as_numpy(truncated))
                            or (self.task.ends_at_success and success)  # as the decision env and the benchmark
                            or idle >= self.idle_stop)
                if done:
                    break
            if reads and not done:  # the writer reads the chunk's frame, as the decision env's
                frame = self.task.frames(self.env, obs, info)[0]
                frame.steps, frame.percepts = i + 1, percepts
                self.written.observe(frame)
        return EpisodeFrames(episode, prompts[0], truth.group, frames, prompts, np.asarray(actions, np.float32),
                             success, np.asarray(kept), self.learner is not None)


_recorder: DemoRecorder | None = None


def _init_recorder(task: Task | str, render_backend: str, replan_every: int | None, frames: str = "every",
                   learner: str | None = None, max_steps: int | None = None, image_size: int | None = None,
                   in_worker: bool = True) -> None:
    global _recorder
    if in_worker:
        from sb3_memret.common.workers import init_pool_worker

        init_pool_worker()
    _recorder = DemoRecorder(task, render_backend, replan_every, frames, learner, max_steps, image_size)


def _record(episode: DemoEpisode) -> EpisodeFrames:
    assert _recorder is not None, "recorder used before its initializer ran"
    return _recorder.record(episode)


class DemoDatasetWriter:
    """A new LeRobotDataset (v3.0, images as PNGs) at ``out`` and the per-episode log beside it. Closing
    finalises it, so an interrupted run keeps every episode saved so far. ``robot_type`` (LeRobot's field) is the
    ManiSkill robot uid the episodes ran with: a camera policy trained on them refuses envs that render another."""

    def __init__(self, out: str | Path, features: dict[str, dict[str, Any]], robot_type: str | None):
        from datasets.utils import logging as datasets_logging
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        self.out = Path(out)
        if self.out.exists():
            raise FileExistsError(f"{self.out} already exists; demonstrations are written to a new folder")
        self.dataset = LeRobotDataset.create(repo_id=f"sb3_memret/{self.out.name}", fps=FPS, root=self.out,
                                             robot_type=robot_type, features=features, use_videos=False,
                                             video_backend="pyav")  # images are PNGs: no video decoder to probe
        self._logging = datasets_logging
        self._bars = datasets_logging.is_progress_bar_enabled()
        datasets_logging.disable_progress_bar()  # a "Map" bar per saved episode would bury the run's own

    def add_episode(self, frames: Iterable[dict[str, Any]], record: dict[str, Any]) -> None:
        """Save one episode's frames and append ``record`` (how it was played) to the episode log."""
        for frame in frames:
            self.dataset.add_frame(frame)
        self.dataset.save_episode()
        with open(self.out / EPISODES_FILE, "a") as f:
            f.write(json.dumps(record) + "\n")

    def close(self) -> None:
        self.dataset.finalize()
        if self._bars:
            self._logging.enable_progress_bar()


def record_demos(
    out: str | Path,
    task: Task | str,
    episodes: Sequence[DemoEpisode],
    render_backend: str = "none",
    n_workers: int = 1,
    replan_every: int | None = None,
    on_episode: Callable[[EpisodeFrames], None] | None = None,
    frames: str = "every",
    learner: str | None = None,
    max_steps: int | None = None,
    image_size: int | None = None,
) -> Path:
    """Record ``episodes`` (``Task.plan_demos``) of ``task``'s expert into a new LeRobotDataset at ``out`` and return
    its folder. ``frames`` (``every`` or ``decisions``) says which control steps it keeps and ``image_size`` the
    square size its cameras are stored at (None: as rendered); ``learner`` (a controller spec) makes it a DAgger
    round, the learner acting and the expert labelling; ``max_steps`` ends each episode after that many control steps
    (None: the task's own limit); ``replan_every`` (None: the task's) the steps executed from each chunk."""
    from sb3_memret.common.workers import map_in_workers

    the_task = make_task(task)
    if learner is not None and n_workers > 1:
        make_controller(learner, the_task)  # a bad spec fails here, before any worker starts (one worker: in-process)
    with_images = check_render_backend(render_backend) != "none"
    features = sized_features(the_task, with_images, image_size)
    chunk_len = the_task.expert().spec.chunk_len if check_frames(frames) == "decisions" else None
    robot = the_task.env_kwargs(with_images, render_backend).get("robot_uids")  # None: the env's own, unrecorded
    writer = DemoDatasetWriter(out, {**features, **(chunk_features(chunk_len) if chunk_len else {})}, robot)

    def save(_: DemoEpisode, recorded: EpisodeFrames) -> None:
        chunks, pads = recorded.chunks(chunk_len) if chunk_len else (None, None)
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
        map_in_workers(_init_recorder, (task, render_backend, replan_every, frames, learner, max_steps, image_size),
                       _record, list(episodes), n_workers, save)
    finally:
        writer.close()
        if _recorder is not None:
            _recorder.env.close()
            _recorder = None
    return Path(out)


def read_episode_log(root: str | Path) -> list[dict]:
    """The per-episode records ``record_demos`` wrote beside the dataset."""
    path = Path(root) / EPISODES_FILE
    return [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []


__all__ = ["DemoDatasetWriter", "DemoRecorder", "EPISODES_FILE", "EpisodeFrames", "FPS", "FRAME_CHOICES", "IDLE_STOP",
           "check_frames", "image_features", "label_chunks", "read_episode_log", "record_demos", "sized_features"]
