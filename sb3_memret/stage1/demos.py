"""Expert demonstrations as a LeRobotDataset (v3.0), written with lerobot's own recording API.

Data design (decided up front; the held-out tests depend on what stays out):

- **Prompts in the data**: the bare instruction (``pick out the cube.``: the expert opens the top
  drawer, as the seed's finetuned π0.5 does) and single-fact prompts
  ``pick out the cube. the cube is in drawer layer L.`` for every layer L. The named layer is the
  cube's layer in most episodes and another layer in the rest (the expert opens the named drawer,
  finds it empty and holds still), so the policy learns to follow the prompt, not the cube.
  With several objects (``objects``, ``n_objects``) the target cycles over the objects and the
  prompts name it (``pick out the tin. the tin is in drawer layer L.``).
- **Prompts kept out**: two-memory prompts, other objects' facts, holding facts and any paraphrase
  of the fact sentence, so ``ablate memcount``, ``ablate prompt`` and ``ablate wording`` stay true
  held-out tests.
- **States off the expert's path**: a share of the episodes executes the expert's actions with
  Gaussian noise on the arm (the labels stay the expert's clean actions), and DAgger rounds
  (``learner=``) let a learned controller act while the expert, which can label any state,
  shadows it and supplies every label.

Per frame: ``observation.state`` (19: what a controller may see; see
``sb3_memret.controllers.observation``), ``action`` (the expert's 7-D end-effector delta pose for
that step), ``task`` (the exact prompt), and with a renderer the two cameras under the keys
π0.5-LIBERO finetuning reads. ``frames="every"`` keeps every control step (lerobot builds action
chunks from consecutive frames, as π0.5's finetuning reads them); ``frames="decisions"`` keeps only
the steps a controller acts at (one per ``replan_every``), each with the expert's labels for the
next ``chunk_len`` steps as ``action_chunk`` (``action_chunk_is_pad`` past the episode's end), and
renders the cameras only there: a camera frame costs ~55 ms here, a control step ~4 ms. An episode
ends at success, at the time limit, or once the expert has held still for ``idle_stop`` steps (an
empty drawer). Episodes are written as they finish; an interrupted run finalises the dataset with
every episode saved so far.
"""

from __future__ import annotations

import json
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers.base import FrozenController
from sb3_memret.controllers.observation import (ACTION_CHUNK_KEY, ACTION_KEY, CHUNK_PAD_KEY, IMAGE_KEYS, IMAGE_SHAPE,
                                                STATE_KEY, TASK_KEY, camera_images, dataset_features,
                                                observation_state, resize_images)
from sb3_memret.tasks.drawer.expert import Phase, ScriptedDrawerController
from sb3_memret.tasks.drawer.cabinet import LAYERS
from sb3_memret.tasks.drawer.objects import object_set
from sb3_memret.tasks.drawer.drawer_cube import DEFAULT_ROBOT
from sb3_memret.controllers.prompts import INSTRUCTION_TEMPLATE, PromptTemplate, build_prompt, instruction_text
from sb3_memret.tasks.drawer.prompts import location_text
from sb3_memret.tasks.base import RENDER_BACKENDS
from sb3_memret.tasks.drawer import DrawerTask

FPS = 20  # pd_ee_delta_pose control frequency of DrawerCubeTakeOut-v1
EPISODES_FILE = "sb3_memret_episodes.jsonl"  # one line per saved episode: how it was played
FRAME_CHOICES = ("every", "decisions")  # which control steps a dataset keeps


def check_frames(frames: str) -> str:
    if frames not in FRAME_CHOICES:
        raise ValueError(f"unknown frames {frames!r}; expected one of {list(FRAME_CHOICES)}")
    return frames


@dataclass(frozen=True)
class PromptMix:
    """How episodes' prompts are drawn: bare, fact naming the cube's layer, fact naming another layer."""

    bare: float = 0.2
    matching: float = 0.6
    mismatched: float = 0.2

    def __post_init__(self) -> None:
        weights = (self.bare, self.matching, self.mismatched)
        if min(weights) < 0 or not np.isclose(sum(weights), 1.0):
            raise ValueError(f"prompt mix {weights} must be non-negative and sum to 1")


@dataclass(frozen=True)
class DemoEpisode:
    """One demonstration to record: placement seed, target layer, prompt, action noise on the arm, target."""

    seed: int
    target_layer: int
    prompt: str
    noise: float = 0.0
    target: str = "cube"


@dataclass
class EpisodeFrames:
    """A recorded episode: the expert's label at every control step, and the kept frames' states and
    camera images (every step, or the decision steps alone: ``frame_steps``)."""

    episode: DemoEpisode
    states: np.ndarray  # (F, 19) at the kept frames
    actions: np.ndarray  # (T, 7): the expert's label at every control step
    images: dict[str, np.ndarray]  # feature -> (F, S, S, 3) uint8, empty without a renderer
    success: bool
    learner_acted: bool
    frame_steps: np.ndarray | None = None  # (F,) the control step of each kept frame; None: every step

    def __post_init__(self) -> None:
        if self.frame_steps is None:
            self.frame_steps = np.arange(len(self.actions))

    def chunks(self, chunk_len: int) -> tuple[np.ndarray, np.ndarray]:
        """Each kept frame's labels for its next ``chunk_len`` steps (F, chunk_len, 7) and the pad mask past the
        episode's end (F, chunk_len)."""
        return label_chunks(self.actions, self.frame_steps, chunk_len)


def label_chunks(actions: np.ndarray, steps: np.ndarray, chunk_len: int) -> tuple[np.ndarray, np.ndarray]:
    """``actions[s : s + chunk_len]`` for each step ``s``, the last label repeated past the end, and its pad mask."""
    raw = np.asarray(steps)[:, None] + np.arange(chunk_len)[None, :]
    return actions[np.minimum(raw, len(actions) - 1)], raw > len(actions) - 1


def plan_episodes(n: int, seed: int = 0, noise: float = 0.0, noisy_fraction: float = 0.5,
                  mix: PromptMix | None = None, objects: str | Sequence[str] = "cube") -> list[DemoEpisode]:
    """``n`` episodes with placement seeds ``seed..seed+n-1``, target layers cycling over the layers and
    targets over ``objects`` (a named set or a list), prompts drawn by ``mix`` and ``noisy_fraction`` of
    them with arm noise ``noise``."""
    names = object_set(objects)
    if n < 1:
        raise ValueError(f"episodes must be >= 1, got {n}")
    if noise < 0 or not 0 <= noisy_fraction <= 1:
        raise ValueError(f"noise must be >= 0 and noisy_fraction in [0, 1], got {noise}, {noisy_fraction}")
    mix = mix or PromptMix()
    rng = np.random.default_rng(seed)
    episodes = []
    for k in range(n):
        layer, target = LAYERS[k % len(LAYERS)], names[(k // len(LAYERS)) % len(names)]
        kind = rng.choice(3, p=[mix.bare, mix.matching, mix.mismatched])
        instruction = instruction_text(target)
        if kind == 0:
            prompt = instruction
        else:
            others = [other for other in LAYERS if other != layer]
            named = layer if kind == 1 else int(rng.choice(others))
            prompt = build_prompt(instruction, [location_text(target, named)], PromptTemplate((INSTRUCTION_TEMPLATE,)))
        noisy = rng.random() < noisy_fraction
        episodes.append(DemoEpisode(seed + k, layer, prompt, noise if noisy else 0.0, target))
    return episodes


def record_episode(env, expert: ScriptedDrawerController, episode: DemoEpisode,
                   learner: FrozenController | None = None, replan_every: int = DrawerTask.replan_every,
                   idle_stop: int = 16, with_images: bool = False, frames: str = "every",
                   image_size: int = IMAGE_SHAPE[0]) -> EpisodeFrames:
    """Play one episode, the expert labelling every step; the learner acts instead when given. ``frames``
    says which steps' observations are kept; camera images are resized to ``image_size``."""
    decisions_only = check_frames(frames) == "decisions"
    paused = getattr(env.unwrapped, "sensors_paused", None) if decisions_only and with_images else None
    rng = np.random.default_rng(episode.seed)
    obs, _ = env.reset(seed=episode.seed, options={"target_layer": episode.target_layer, "target": episode.target})
    expert.reset([episode.seed])
    if learner is not None:
        learner.reset([episode.seed])
    states, actions, kept, images = [], [], [], {key: [] for key in IMAGE_KEYS} if with_images else {}
    idle, success, done = 0, False, False
    while not done:
        labels = expert.act(obs, [episode.prompt])[0][:replan_every]
        executed = learner.act(obs, [episode.prompt])[0][:replan_every] if learner is not None else labels.copy()
        for i, (label, action) in enumerate(zip(labels, executed)):
            if i == 0 or not decisions_only:
                kept.append(len(actions))
                states.append(observation_state(obs)[0])
                for key, frame in camera_images(obs).items() if with_images else ():
                    images[key].append(resize_images(frame, image_size)[0])
            actions.append(label)
            if episode.noise:
                action = action.copy()
                action[:6] = np.clip(action[:6] + rng.normal(0.0, episode.noise, 6), -1.0, 1.0)
            with paused() if paused is not None and i < len(labels) - 1 else nullcontext():
                obs, _, terminated, truncated, info = env.step(action)
            success = bool(info["success"])
            idle = idle + 1 if expert.phases()[0] is Phase.IDLE else 0
            if terminated or truncated or idle >= idle_stop:
                done = True
                break
    return EpisodeFrames(episode, np.asarray(states, np.float32), np.asarray(actions, np.float32),
                         {key: np.stack(frames) for key, frames in images.items()}, success, learner is not None,
                         np.asarray(kept))


class _Recorder:
    """A task env, the expert and an optional learner, recording episodes one after another."""

    def __init__(self, render_backend: str, learner: str | None, replan_every: int, max_steps: int | None,
                 objects: tuple[str, ...], n_objects: int, frames: str = "every", image_size: int = IMAGE_SHAPE[0]):
        self.with_images = render_backend != "none"
        self.frames, self.image_size = frames, image_size
        limit = {} if max_steps is None else {"max_episode_steps": max_steps}
        self.env = DrawerTask().make_env(obs_mode="rgb" if self.with_images else "state_dict", render_backend=render_backend,
                                 objects=objects, n_objects=n_objects, robot_uids=DEFAULT_ROBOT, **limit)
        self.expert = ScriptedDrawerController()
        self.expert.check_env(self.env)
        self.learner = make_controller(learner) if learner is not None else None
        if self.learner is not None:
            self.learner.check_env(self.env)
        self.replan_every = replan_every

    def record(self, episode: DemoEpisode) -> EpisodeFrames:
        return record_episode(self.env, self.expert, episode, self.learner, self.replan_every,
                              with_images=self.with_images, frames=self.frames, image_size=self.image_size)


_recorder: _Recorder | None = None


def _init_recorder(render_backend: str, learner: str | None, replan_every: int, max_steps: int | None,
                   objects: tuple[str, ...], n_objects: int, frames: str = "every", image_size: int = IMAGE_SHAPE[0],
                   in_worker: bool = True) -> None:
    global _recorder
    if in_worker:
        from sb3_memret.common.workers import init_pool_worker

        init_pool_worker()
    _recorder = _Recorder(render_backend, learner, replan_every, max_steps, objects, n_objects, frames, image_size)


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
    episodes: Sequence[DemoEpisode],
    render_backend: str = "none",
    learner: str | None = None,
    n_workers: int = 1,
    replan_every: int = DrawerTask.replan_every,
    max_steps: int | None = None,
    on_episode: Callable[[EpisodeFrames], None] | None = None,
    objects: str | Sequence[str] = "cube",
    n_objects: int = 1,
    frames: str = "every",
    image_size: int = IMAGE_SHAPE[0],
) -> Path:
    """Record ``episodes`` into a new LeRobotDataset at ``out`` and return its folder.

    ``learner`` (a controller spec) makes this a DAgger round: the learner acts, the expert labels.
    ``max_steps`` shortens the task's 400-step limit (quick checks). ``objects`` and ``n_objects``
    set what the drawers hide; every episode's target must be one of ``objects``. ``frames``
    (``every`` or ``decisions``) and ``image_size`` (cameras resized to it) shape the frames kept.
    """
    check_frames(frames)
    if not 16 <= image_size <= IMAGE_SHAPE[0]:
        raise ValueError(f"image_size must be in [16, {IMAGE_SHAPE[0]}] (the cameras render {IMAGE_SHAPE[0]}), "
                         f"got {image_size}")
    names = object_set(objects)
    strangers = sorted({e.target for e in episodes} - set(names))
    if strangers:
        raise ValueError(f"episodes target {strangers}, which are not among the objects {list(names)}")

    if render_backend not in RENDER_BACKENDS:
        raise ValueError(f"unknown render backend {render_backend!r}; expected one of {list(RENDER_BACKENDS)}")
    if learner is not None:
        make_controller(learner)  # a bad spec fails here, before any worker starts
    chunk_len = ScriptedDrawerController().spec.chunk_len if frames == "decisions" else None
    writer = DemoDatasetWriter(out, dataset_features(render_backend != "none", image_size, chunk_len), DEFAULT_ROBOT)

    def save(_: DemoEpisode, recorded: EpisodeFrames) -> None:
        chunks, pads = recorded.chunks(chunk_len) if chunk_len else (None, None)
        rows = ({STATE_KEY: recorded.states[i], ACTION_KEY: recorded.actions[step], TASK_KEY: recorded.episode.prompt,
                 **({ACTION_CHUNK_KEY: chunks[i], CHUNK_PAD_KEY: pads[i]} if chunk_len else {}),
                 **{key: images[i] for key, images in recorded.images.items()}}
                for i, step in enumerate(recorded.frame_steps))
        writer.add_episode(rows, {**asdict(recorded.episode), "frames": len(recorded.frame_steps),
                                  "steps": len(recorded.actions), "success": recorded.success, "learner": learner})
        if on_episode is not None:
            on_episode(recorded)

    from sb3_memret.common.workers import map_in_workers

    global _recorder
    try:
        map_in_workers(_init_recorder, (render_backend, learner, replan_every, max_steps, names, n_objects, frames,
                                        image_size), _record, list(episodes), n_workers, save)
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


__all__ = ["DemoDatasetWriter", "DemoEpisode", "EpisodeFrames", "FPS", "FRAME_CHOICES", "PromptMix", "check_frames",
           "label_chunks", "plan_episodes", "read_episode_log", "record_demos", "record_episode"]
