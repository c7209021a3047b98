"""Demonstration datasets as arrays for ``finetune``: frames, labels, episodes and prompts, one task's or several.

``load_demonstrations`` reads the LeRobotDatasets ``sb3-memret demos`` wrote for one task, checking their features
against its layout; ``load_task_demonstrations`` merges several tasks' on the union of their layouts, marking each
frame's own entries (``Demonstrations.known``). Camera images stay on disk (``CameraFrames``) and are read a dataset
at a time where they are used. ``hindsight_objects`` reads what each prompt was about from where its
episodes' hands end, and ``validation_episodes`` draws the held-out episodes.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterator, Mapping, Sequence

import numpy as np

from sb3_memret.controllers.harness_proprio import HARNESS_PROPRIO_NAMES, with_harness_proprio
from sb3_memret.controllers.learned.processing import state_columns
from sb3_memret.controllers.observation import ACTION_CHUNK_KEY, ACTION_DIM, ACTION_KEY, CHUNK_PAD_KEY, IMAGE_KEYS, STATE_KEY
from sb3_memret.tasks import Task, make_task


@dataclass(frozen=True)
class CameraFrames:
    """One camera's uint8 frames (S, S, 3) across the datasets, read from disk a dataset at a time (``blocks``): a
    multi-task set's images outgrow memory (170 chunks of MIKASA demonstrations held 9 GB, twice that while joined)
    where a frozen trunk's features of them do not."""

    key: str
    roots: tuple[Path, ...]
    spans: tuple[int, ...]  # each dataset's frame count, in order
    frame_shape: tuple[int, ...]

    @property
    def shape(self) -> tuple[int, ...]:
        return (sum(self.spans), *self.frame_shape)

    def __len__(self) -> int:
        return sum(self.spans)

    def blocks(self) -> Iterator[np.ndarray]:
        """Each dataset's frames, in order."""
        for root, span in zip(self.roots, self.spans):
            yield _read_frames(root, self.key, span)

    def array(self) -> np.ndarray:
        """Every frame in one array (an encoder trained from pixels reads them all at every step)."""
        return np.concatenate([*self.blocks()]) if self.roots else np.zeros((0, *self.frame_shape), np.uint8)

    def take(self, idx: np.ndarray) -> np.ndarray:
        """Frames ``idx``, in that order, reading only the datasets that hold them."""
        idx = np.asarray(idx, dtype=np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= len(self)):
            raise IndexError(f"frame indices must lie in [0, {len(self)}), got {idx.min()}..{idx.max()}")
        out = np.zeros((len(idx), *self.frame_shape), np.uint8)
        starts = np.r_[0, np.cumsum(self.spans)]
        for i, (root, span) in enumerate(zip(self.roots, self.spans)):
            inside = (idx >= starts[i]) & (idx < starts[i + 1])
            if inside.any():
                out[inside] = _read_frames(root, self.key, span)[idx[inside] - starts[i]]
        return out

    @classmethod
    def join(cls, parts: Sequence["CameraFrames"]) -> "CameraFrames":
        """One camera's frames of several sets, in order; sets of other image sizes are refused."""
        shapes = {part.frame_shape for part in parts}
        if len(shapes) != 1 or len({part.key for part in parts}) != 1:
            raise ValueError(f"cannot join one camera's frames of sizes {sorted(shapes)} or cameras "
                             f"{sorted({part.key for part in parts})}")
        return cls(parts[0].key, tuple(r for p in parts for r in p.roots), tuple(n for p in parts for n in p.spans),
                   shapes.pop())


def _read_frames(root: Path, key: str, span: int) -> np.ndarray:
    """Camera ``key``'s frames of the dataset at ``root`` (lerobot's reader), checked to number ``span``."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset(f"local/{root.name}", root=root, video_backend="pyav")
    frames = np.asarray(dataset.hf_dataset.with_format("numpy")[key], dtype=np.uint8)
    if len(frames) != span:
        raise ValueError(f"{root} holds {len(frames)} frames of {key!r} where it held {span} when read: the dataset "
                         "changed during the finetune")
    return frames


@dataclass
class Demonstrations:
    """All frames of one or more datasets as arrays (the camera images as where they lie on disk), with each frame's
    chunk of target indices."""

    states: np.ndarray  # (N, D) float32, in the task's layout (state_names)
    actions: np.ndarray  # (N, 7) float32
    episodes: np.ndarray  # (N,) a global episode id
    task_ids: np.ndarray  # (N,) index into tasks
    tasks: list[str]
    images: dict[str, CameraFrames]  # feature -> its (N, S, S, 3) uint8 frames on disk, empty for state-only data
    state_names: tuple[str, ...] = ()
    chunks: np.ndarray | None = None  # (N, H, 7): decision frames' label chunks; None when every step is a frame
    chunk_pad: np.ndarray | None = None  # (N, H) steps of a chunk past the episode's end
    known: np.ndarray | None = None  # (N, D) the state entries each frame's task has (several tasks); None: all
    robot: str | None = None  # the robot the camera images show (the datasets' robot_type); None: no cameras
    spans: tuple[int, ...] = ()  # frames of each dataset read, in order
    sources: np.ndarray | None = None  # (N,) the index of the task each frame was recorded on (several); None: one

    def targets(self, chunk_len: int) -> tuple[np.ndarray, np.ndarray]:
        """(N, chunk_len, 7) target labels of every frame and their (N, chunk_len) pad mask."""
        if self.chunks is None:
            index, pad = self.chunk_indices(chunk_len)
            return self.actions[index], pad
        if self.chunks.shape[1] < chunk_len:
            raise ValueError(f"the datasets hold chunks of {self.chunks.shape[1]} labels; the policy predicts "
                             f"{chunk_len}: lower chunk_len or record longer chunks")
        return self.chunks[:, :chunk_len], self.chunk_pad[:, :chunk_len]

    def with_harness_proprio(self) -> "Demonstrations":
        """These frames with MIKASA's harness proprioception appended to their state (derived from the hand pose and
        fingers, ``with_harness_proprio``), known in every frame: what a controller on the harness's inputs reads."""
        states, names = with_harness_proprio(self.states, self.state_names)
        known = None if self.known is None else np.c_[self.known, np.ones((len(states), len(HARNESS_PROPRIO_NAMES)),
                                                                          dtype=bool)]
        return replace(self, states=states, state_names=names, known=known)

    def last_frames(self) -> np.ndarray:
        """The index of each episode's last frame (episodes are runs of equal ids in ``episodes``)."""
        return np.r_[np.flatnonzero(np.diff(self.episodes)), len(self.episodes) - 1]

    def prompt_ends(self) -> np.ndarray:
        """The index of the last frame of each run of one episode's frames under one prompt: each episode's last
        frame, and for a task whose writer records progress (``the lime cube was touched.``) each frame before the
        prompt changed."""
        changed = (np.diff(self.episodes) != 0) | (np.diff(self.task_ids) != 0)
        return np.r_[np.flatnonzero(changed), len(self.episodes) - 1]

    def chunk_indices(self, chunk_len: int) -> tuple[np.ndarray, np.ndarray]:
        """(N, chunk_len) frame indices of each frame's target chunk and the mask of steps past its episode."""
        last = self.last_frames()
        ends = np.repeat(last, np.diff(np.r_[-1, last]))  # each frame's episode's last frame
        raw = np.arange(len(self.actions))[:, None] + np.arange(chunk_len)[None, :]
        return np.minimum(raw, ends[:, None]), raw > ends[:, None]


def load_demonstrations(roots: Sequence[str | Path], task: str | Task) -> Demonstrations:
    """Read LeRobotDatasets written by ``sb3-memret demos`` for ``task`` (lerobot's reader), checking their
    features against the task's layout."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if not roots:
        raise ValueError("no dataset given")
    task = make_task(task)
    names = task.state_names()
    parts, tasks, offset, image_keys, chunked, robots = [], [], 0, None, None, {}
    for root in map(dataset_root, roots):
        dataset = LeRobotDataset(f"local/{root.name}", root=root, video_backend="pyav")  # no videos to decode
        features = dataset.meta.features
        _check_feature(features, STATE_KEY, (len(names),), root, task.name)
        _check_feature(features, ACTION_KEY, (ACTION_DIM,), root, task.name)
        if tuple(features[STATE_KEY].get("names") or names) != names:
            raise ValueError(f"{root}: its state entries {features[STATE_KEY]['names']} are not task "
                             f"{task.name!r}'s layout {list(names)}")
        keys = tuple(k for k in IMAGE_KEYS if k in features)
        if image_keys is not None and keys != image_keys:
            raise ValueError(f"{root} has cameras {list(keys)} but an earlier dataset has {list(image_keys)}; "
                             "train on datasets recorded with the same render backend")
        has_chunks = ACTION_CHUNK_KEY in features
        if chunked is not None and has_chunks != chunked:
            raise ValueError(f"{root} keeps {'decision' if has_chunks else 'every'} frames but an earlier dataset "
                             "does not; train on datasets recorded with the same --frames")
        image_keys, chunked = keys, has_chunks
        if keys:
            robots[str(root)] = dataset.meta.robot_type
        columns = dataset.hf_dataset.with_format("numpy")
        local = dataset.meta.tasks["task_index"]
        task_map = np.zeros(int(local.max()) + 1, dtype=np.int64)
        task_map[local.to_numpy()] = [_task_id(task, tasks) for task in local.index]
        episode_index = np.asarray(columns["episode_index"])
        part = {
            "states": np.asarray(columns[STATE_KEY], dtype=np.float32),
            "actions": np.asarray(columns[ACTION_KEY], dtype=np.float32),
            "episodes": episode_index + offset,
            "task_ids": task_map[np.asarray(columns["task_index"])],
            "images": {k: CameraFrames(k, (root,), (len(episode_index),), tuple(features[k]["shape"])) for k in keys},
        }
        if has_chunks:
            part["chunks"] = np.asarray(columns[ACTION_CHUNK_KEY], dtype=np.float32)
            part["chunk_pad"] = np.asarray(columns[CHUNK_PAD_KEY], dtype=bool)
        offset = int(part["episodes"].max()) + 1
        parts.append(part)
    sizes = {p["images"][k].frame_shape for p in parts for k in p["images"]}
    if len(sizes) > 1:
        raise ValueError(f"the datasets' camera images differ in size {sorted(sizes)}; record them with one --image-size")
    return Demonstrations(
        robot=_one_robot(robots),
        states=np.concatenate([p["states"] for p in parts]),
        actions=np.concatenate([p["actions"] for p in parts]),
        episodes=np.concatenate([p["episodes"] for p in parts]),
        task_ids=np.concatenate([p["task_ids"] for p in parts]),
        tasks=tasks,
        images={k: CameraFrames.join([p["images"][k] for p in parts]) for k in (image_keys or ())},
        state_names=names,
        chunks=np.concatenate([p["chunks"] for p in parts]) if chunked else None,
        chunk_pad=np.concatenate([p["chunk_pad"] for p in parts]) if chunked else None,
        spans=tuple(len(p["states"]) for p in parts),
    )


def load_task_demonstrations(datasets: Mapping[str | Task, Sequence[str | Path]]) -> tuple[Demonstrations, list[Task]]:
    """Read each task's datasets (``load_demonstrations``) into one set on the union of the tasks' layouts (entries
    in order of first appearance), with ``known`` marking each frame's own entries (the others hold 0)."""
    if not datasets:
        raise ValueError("no dataset given")
    tasks = [make_task(task) for task in datasets]
    parts = [load_demonstrations(roots, task) for task, roots in zip(tasks, datasets.values())]
    cameras = {task.name: (tuple(part.images), next((im.shape[1:] for im in part.images.values()), None))
               for task, part in zip(tasks, parts)}
    if len(set(cameras.values())) > 1:
        raise ValueError(f"the tasks' datasets hold different cameras or image sizes {cameras}: record them all with "
                         "the same render backend and --image-size")
    if len({part.chunks is None for part in parts}) > 1:
        raise ValueError("some tasks' datasets keep every frame and others decision frames only; record them all "
                         "with the same --frames")
    names = tuple(dict.fromkeys(name for part in parts for name in part.state_names))
    prompts: list[str] = []
    states, known, task_ids, episodes, offset = [], [], [], [], 0
    for part in parts:
        columns = state_columns(names, part.state_names, "the union layout")
        block = np.zeros((len(part.states), len(names)), dtype=np.float32)
        block[:, columns] = part.states
        mask = np.zeros(block.shape, dtype=bool)
        mask[:, columns] = True
        states.append(block)
        known.append(mask)
        task_ids.append(np.array([_task_id(part.tasks[i], prompts) for i in part.task_ids], dtype=np.int64))
        episodes.append(part.episodes + offset)
        offset = int(episodes[-1].max()) + 1
    chunked = parts[0].chunks is not None
    return Demonstrations(
        robot=_one_robot({task.name: part.robot for task, part in zip(tasks, parts) if part.images}),
        states=np.concatenate(states), actions=np.concatenate([p.actions for p in parts]),
        episodes=np.concatenate(episodes), task_ids=np.concatenate(task_ids), tasks=prompts,
        images={k: CameraFrames.join([p.images[k] for p in parts]) for k in parts[0].images}, state_names=names,
        chunks=np.concatenate([p.chunks for p in parts]) if chunked else None,
        chunk_pad=np.concatenate([p.chunk_pad for p in parts]) if chunked else None,
        known=np.concatenate(known), spans=tuple(span for part in parts for span in part.spans),
        sources=np.concatenate([np.full(len(part.states), k, dtype=np.int64) for k, part in enumerate(parts)])), tasks


def _one_robot(robots: Mapping[str, str | None]) -> str | None:
    """The one robot every dataset's cameras show (None without cameras); datasets of different robots are refused,
    since a camera policy learns what its robot looks like."""
    if len(set(robots.values())) > 1:
        raise ValueError(f"the datasets' cameras show different robots {dict(robots)}: record them all with one robot")
    return next(iter(robots.values()), None)


def _task_id(task: str, tasks: list[str]) -> int:
    if task not in tasks:
        tasks.append(task)
    return tasks.index(task)


def _check_feature(features: dict, key: str, shape: tuple[int, ...], root: Path, task: str) -> None:
    if key not in features or tuple(features[key]["shape"]) != shape:
        found = features.get(key, {}).get("shape")
        raise ValueError(f"{root}: feature {key!r} has shape {found}, expected {shape} (task {task!r}'s "
                         "demonstration layout)")


def dataset_prompts(roots: Sequence[str | Path]) -> list[str]:
    """The prompts the datasets hold, each once, read from their metadata alone (lerobot's reader): seconds where
    reading the frames of a multi-task set takes minutes, so a prompt outside the contract is refused first."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    prompts: dict[str, None] = {}
    for root in map(dataset_root, roots):
        prompts.update(dict.fromkeys(LeRobotDatasetMetadata(f"local/{root.name}", root=root).tasks.index))
    return list(prompts)


def has_cameras(roots: Sequence[str | Path]) -> bool:
    """Whether the first dataset holds camera images (read from its metadata alone)."""
    import json

    info = dataset_root(roots[0]) / "meta" / "info.json"
    return any(key in json.loads(info.read_text())["features"] for key in IMAGE_KEYS)


def dataset_root(root: str | Path) -> Path:
    """``root`` as a path, or a FileNotFoundError when it holds no LeRobotDataset."""
    root = Path(root)
    if not (root / "meta" / "info.json").is_file():
        raise FileNotFoundError(f"{root} is not a LeRobotDataset (no meta/info.json); write one with "
                                "`sb3-memret demos --out DIR`")
    return root


def hindsight_objects(demos: Demonstrations, hand_names: Sequence[str], objects: Sequence[str],
                      frames: np.ndarray | None = None) -> np.ndarray:
    """(len(demos.tasks),) for each prompt the index in ``objects`` of the object its episodes' hands end nearest
    (by the ``<object>_x/_y/_z`` and ``hand_names`` state entries at the last frame under that prompt: an episode's
    last, or the one before a progress fact changed it, ``prompt_ends``; only ends in the boolean ``frames`` vote),
    or -1 where no object is nearest in more than half of them: what the prompt was about, read from where the hand
    went. Exact for an expert's episodes; a DAgger round's, where the learner drove, are outvoted when it erred."""
    def columns(names: Sequence[str]) -> np.ndarray:
        return state_columns(demos.state_names, names, "the datasets' state (for pointer hindsight)")

    last = demos.prompt_ends()
    if frames is not None:
        last = last[frames[last]]
    hand = demos.states[last][:, columns(hand_names)]
    where = np.stack([demos.states[last][:, columns([f"{obj}_{axis}" for axis in "xyz"])] for obj in objects], axis=1)
    distance = np.linalg.norm(where - hand[:, None], axis=-1)
    if demos.known is not None:  # an object its episode's task does not have is never the nearest
        has = np.stack([demos.known[last][:, columns([f"{obj}_x"])[0]] for obj in objects], axis=1)
        distance = np.where(has, distance, np.inf)
    nearest = distance.argmin(axis=1)
    prompts = demos.task_ids[last]
    targets = np.full(len(demos.tasks), -1)
    for prompt in np.unique(prompts):
        votes = np.bincount(nearest[prompts == prompt], minlength=len(objects))
        if votes.max() * 2 > votes.sum():
            targets[prompt] = votes.argmax()
    return targets


def validation_episodes(episodes: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """The episode ids held out for validation: ``fraction`` of them, drawn by ``rng`` (a finetune's first draw from
    ``default_rng(seed)``, so a finetune's split can be rebuilt from its seed)."""
    ids = np.unique(episodes)
    n_val = int(round(len(ids) * fraction))
    return rng.choice(ids, size=n_val, replace=False) if n_val else np.array([], dtype=np.int64)


__all__ = ["CameraFrames", "Demonstrations", "dataset_prompts", "has_cameras", "hindsight_objects",
           "load_demonstrations", "load_task_demonstrations", "validation_episodes"]
