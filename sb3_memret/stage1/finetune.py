"""Train the project's learned controller from demonstration datasets (behaviour cloning of action chunks).

Every frame of every episode is a sample: its state (and camera images, when the datasets have
them), its prompt as frozen MiniLM token features, and as target the expert's labels for the
next ``chunk_len`` control steps of the same episode (steps past the episode's end are padding, left
out of the L1 loss, as lerobot's ``action_is_pad``): read from the following frames of a dataset
that keeps every step, or from each frame's ``action_chunk`` in one that keeps decision frames only.
Several datasets (the expert's, then DAgger rounds) train one policy together; datasets of several tasks
(``datasets`` as a mapping from each task to its datasets) train one multi-task policy, on the union of their
layouts: each frame's perception loss covers only the entries its own task has.

Cameras: a frozen pretrained trunk's features are computed once per frame before training (the
trainable heads then cost little per step); a network trained from pixels sees each batch with
random shifts (``image_shift``). The state the policy reads is picked by name from the task's
layout: all of it, or with ``state="proprio"`` only what a robot reads of itself; the entries it does
not read (the simulator's detection, drawer openings) become the policy's ``perceived_names``: its
perception head estimates them from the images, trained on the simulator's labels (``perception_coef``),
and its action head reads the estimates. (Measured here: frozen EfficientNet-Lite0 features locate the
cube within 0.8 cm and its yaw within 7 degrees, ``scripts/probe_camera_features.py``, yet behaviour
cloning alone did not learn to use them.)
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np
import torch
from torch.nn import functional as F

from sb3_memret.controllers.learned.configuration import LearnedPolicyConfig, perceived_objects
from sb3_memret.controllers.learned.modeling import LearnedPolicy, chunk_loss, pointer_ambiguity
from sb3_memret.controllers.learned.processing import PromptTokenizer, state_columns
from sb3_memret.controllers.learned.vision import shift_augment
from sb3_memret.controllers.observation import ACTION_CHUNK_KEY, ACTION_DIM, ACTION_KEY, CHUNK_PAD_KEY, IMAGE_KEYS, STATE_KEY
from sb3_memret.prompts import INSTRUCTION_TEMPLATE, PromptTemplate, parse_prompt
from sb3_memret.tasks import DEFAULT_TASK, Task, make_task

LOG_FILE = "train_log.csv"
POINTER_TARGETS_FILE = "pointer_targets.json"  # finetune's hindsight target of each training prompt, for reading
STATE_CHOICES = ("full", "proprio")  # the whole state layout, or what a robot reads of itself
FEATURE_BATCH = 64  # frames per batch when a frozen trunk's features are computed


@dataclass(frozen=True)
class FinetuneSettings:
    """Optimisation settings of ``finetune``."""

    steps: int = 20_000
    batch_size: int = 256
    learning_rate: float = 1e-3
    weight_decay: float = 1e-4
    validation_fraction: float = 0.1
    seed: int = 0
    image_shift: int = 4  # pixels of random shift on camera images, for encoders trained from pixels
    # weight of the perception loss: a camera policy's perception head regresses the state entries it does not read
    # (the simulator's detection, drawer openings), normalised; 0 leaves the policy without a perception head
    perception_coef: float = 1.0
    # weight of the pointer's hindsight loss: a cross-entropy between each training prompt's pointer weights and the
    # object its demonstrations' hands end nearest (``hindsight_objects``); 0 leaves the pointer to the action loss
    pointer_hindsight: float = 0.0

    def __post_init__(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or self.learning_rate <= 0 or min(
                self.image_shift, self.perception_coef, self.pointer_hindsight) < 0:
            raise ValueError(f"steps and batch_size must be >= 1, learning_rate > 0, image_shift, perception_coef "
                             f"and pointer_hindsight >= 0: {self}")
        if not 0 <= self.validation_fraction < 1:
            raise ValueError(f"validation_fraction must lie in [0, 1), got {self.validation_fraction}")


@dataclass
class Demonstrations:
    """All frames of one or more datasets as arrays, with each frame's chunk of target indices."""

    states: np.ndarray  # (N, D) float32, in the task's layout (state_names)
    actions: np.ndarray  # (N, 7) float32
    episodes: np.ndarray  # (N,) a global episode id
    task_ids: np.ndarray  # (N,) index into tasks
    tasks: list[str]
    images: dict[str, np.ndarray]  # feature -> (N, S, S, 3) uint8, empty for state-only data
    state_names: tuple[str, ...] = ()
    chunks: np.ndarray | None = None  # (N, H, 7): decision frames' label chunks; None when every step is a frame
    chunk_pad: np.ndarray | None = None  # (N, H) steps of a chunk past the episode's end
    known: np.ndarray | None = None  # (N, D) the state entries each frame's task has (several tasks); None: all

    def targets(self, chunk_len: int) -> tuple[np.ndarray, np.ndarray]:
        """(N, chunk_len, 7) target labels of every frame and their (N, chunk_len) pad mask."""
        if self.chunks is None:
            index, pad = self.chunk_indices(chunk_len)
            return self.actions[index], pad
        if self.chunks.shape[1] < chunk_len:
            raise ValueError(f"the datasets hold chunks of {self.chunks.shape[1]} labels; the policy predicts "
                             f"{chunk_len}: lower chunk_len or record longer chunks")
        return self.chunks[:, :chunk_len], self.chunk_pad[:, :chunk_len]

    def last_frames(self) -> np.ndarray:
        """The index of each episode's last frame (episodes are runs of equal ids in ``episodes``)."""
        return np.r_[np.flatnonzero(np.diff(self.episodes)), len(self.episodes) - 1]

    def chunk_indices(self, chunk_len: int) -> tuple[np.ndarray, np.ndarray]:
        """(N, chunk_len) frame indices of each frame's target chunk and the mask of steps past its episode."""
        last = self.last_frames()
        ends = np.repeat(last, np.diff(np.r_[-1, last]))  # each frame's episode's last frame
        raw = np.arange(len(self.actions))[:, None] + np.arange(chunk_len)[None, :]
        return np.minimum(raw, ends[:, None]), raw > ends[:, None]


def load_demonstrations(roots: Sequence[str | Path], task: str | Task = DEFAULT_TASK) -> Demonstrations:
    """Read LeRobotDatasets written by ``sb3-memret demos`` for ``task`` (lerobot's reader), checking their
    features against the task's layout."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if not roots:
        raise ValueError("no dataset given")
    task = make_task(task)
    names = task.state_names()
    parts, tasks, offset, image_keys, chunked = [], [], 0, None, None
    for root in roots:
        root = Path(root)
        if not (root / "meta" / "info.json").is_file():
            raise FileNotFoundError(f"{root} is not a LeRobotDataset (no meta/info.json); write one with "
                                    "`sb3-memret demos --out DIR`")
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
            "images": {k: np.asarray(columns[k], dtype=np.uint8) for k in keys},
        }
        if has_chunks:
            part["chunks"] = np.asarray(columns[ACTION_CHUNK_KEY], dtype=np.float32)
            part["chunk_pad"] = np.asarray(columns[CHUNK_PAD_KEY], dtype=bool)
        offset = int(part["episodes"].max()) + 1
        parts.append(part)
    sizes = {p["images"][k].shape[1:] for p in parts for k in p["images"]}
    if len(sizes) > 1:
        raise ValueError(f"the datasets' camera images differ in size {sorted(sizes)}; record them with one --image-size")
    return Demonstrations(
        states=np.concatenate([p["states"] for p in parts]),
        actions=np.concatenate([p["actions"] for p in parts]),
        episodes=np.concatenate([p["episodes"] for p in parts]),
        task_ids=np.concatenate([p["task_ids"] for p in parts]),
        tasks=tasks,
        images={k: np.concatenate([p["images"][k] for p in parts]) for k in (image_keys or ())},
        state_names=names,
        chunks=np.concatenate([p["chunks"] for p in parts]) if chunked else None,
        chunk_pad=np.concatenate([p["chunk_pad"] for p in parts]) if chunked else None,
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
        states=np.concatenate(states), actions=np.concatenate([p.actions for p in parts]),
        episodes=np.concatenate(episodes), task_ids=np.concatenate(task_ids), tasks=prompts,
        images={k: np.concatenate([p.images[k] for p in parts]) for k in parts[0].images}, state_names=names,
        chunks=np.concatenate([p.chunks for p in parts]) if chunked else None,
        chunk_pad=np.concatenate([p.chunk_pad for p in parts]) if chunked else None,
        known=np.concatenate(known)), tasks


def _task_id(task: str, tasks: list[str]) -> int:
    if task not in tasks:
        tasks.append(task)
    return tasks.index(task)


def _check_feature(features: dict, key: str, shape: tuple[int, ...], root: Path, task: str) -> None:
    if key not in features or tuple(features[key]["shape"]) != shape:
        found = features.get(key, {}).get("shape")
        raise ValueError(f"{root}: feature {key!r} has shape {found}, expected {shape} (task {task!r}'s "
                         "demonstration layout)")


def has_cameras(roots: Sequence[str | Path]) -> bool:
    """Whether the first dataset holds camera images (read from its metadata alone)."""
    import json

    info = Path(roots[0]) / "meta" / "info.json"
    if not info.is_file():
        raise FileNotFoundError(f"{roots[0]} is not a LeRobotDataset (no meta/info.json)")
    return any(key in json.loads(info.read_text())["features"] for key in IMAGE_KEYS)


def training_instructions(prompts: Sequence[str], instructions: Sequence[str],
                          fact_templates: Sequence[str]) -> tuple[str, ...]:
    """The instructions a policy trained on ``prompts`` accepts: the one instruction they hold, or
    the templates ``instructions`` when they hold several (``pick out the {entity}.``: any object word)."""
    template = PromptTemplate(tuple(instructions), tuple(fact_templates))
    held = sorted({parse_prompt(prompt, template).instruction for prompt in prompts})
    return tuple(instructions) if len(held) > 1 else tuple(held)


def state_names_for(task: Task, state: str) -> tuple[str, ...]:
    """The state entries a policy reads: ``full`` (the task's layout) or ``proprio`` (what a robot reads of itself)."""
    if state not in STATE_CHOICES:
        raise ValueError(f"unknown state {state!r}; expected one of {list(STATE_CHOICES)}")
    return task.state_names() if state == "full" else task.proprio_names()


def hindsight_objects(demos: Demonstrations, hand_names: Sequence[str], objects: Sequence[str],
                      frames: np.ndarray | None = None) -> np.ndarray:
    """(len(demos.tasks),) for each prompt the index in ``objects`` of the object its episodes' hands end nearest
    (by the ``<object>_x/_y/_z`` and ``hand_names`` state entries at each episode's last frame; only episodes
    whose last frame is in the boolean ``frames`` vote), or -1 where no object is nearest in more than half of
    them: what the prompt was about, read from where the hand went. Exact for an expert's episodes; a DAgger
    round's, where the learner drove, are outvoted when it erred."""
    def columns(names: Sequence[str]) -> np.ndarray:
        return state_columns(demos.state_names, names, "the datasets' state (for pointer hindsight)")

    last = demos.last_frames()
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


def camera_inputs(model: LearnedPolicy, images: dict[str, np.ndarray], keys: Sequence[str]) -> list[torch.Tensor]:
    """What the policy's camera heads read for every frame: a frozen trunk's features (computed here once, in
    batches, kept as float16), or the uint8 images themselves (channels first) for encoders trained from pixels."""
    frames = [torch.from_numpy(images[key]).permute(0, 3, 1, 2) for key in keys]
    if model.trunk is None:
        return frames
    return [torch.cat([model.trunk(x[i: i + FEATURE_BATCH].float() / 255.0).half()
                       for i in range(0, len(x), FEATURE_BATCH)]) for x in frames]


def finetune(
    datasets: Sequence[str | Path] | Mapping[str | Task, Sequence[str | Path]],
    out: str | Path,
    config: LearnedPolicyConfig | None = None,
    settings: FinetuneSettings | None = None,
    tokenizer: PromptTokenizer | None = None,
    on_step: Callable[[int, float], None] | None = None,
    task: str | Task | None = None,
    state: str = "full",
    cameras: bool = True,
) -> Path:
    """Train a LearnedPolicy on ``datasets`` of ``task`` (default the drawer), or on a mapping from each of several
    tasks to its datasets (one multi-task policy), and save it to ``out`` (``save_pretrained``); returns ``out``.
    ``state`` picks the state entries it reads (``full`` or ``proprio``); ``cameras=False`` leaves the datasets'
    camera images out. The prompt contract is the config's fact templates for the drawer, the tasks' own templates
    (together) for any other."""
    settings = settings or FinetuneSettings()
    if isinstance(datasets, Mapping):
        if task is not None:
            raise ValueError(f"datasets given per task name their tasks; task {task!r} is not needed")
        demos, tasks = load_task_demonstrations(datasets)
    else:
        tasks = [make_task(task if task is not None else DEFAULT_TASK)]
        demos = load_demonstrations(datasets, tasks[0])
    if config is None:
        template = tasks_template(tasks)
        config = LearnedPolicyConfig(fact_templates=template.fact_templates, instructions=template.instructions)
    torch.manual_seed(settings.seed)
    rng = np.random.default_rng(settings.seed)
    drawer = [t.name for t in tasks] == [DEFAULT_TASK]
    instructions = (INSTRUCTION_TEMPLATE,) if drawer else config.instructions
    config = replace(config, instructions=training_instructions(demos.tasks, instructions, config.fact_templates))
    for prompt in demos.tasks:
        parse_prompt(prompt, config.prompt_template)  # a dataset prompt outside the contract is refused
    names = state_names_for(tasks[0], state)
    for other in tasks[1:]:
        if state_names_for(other, state) != names:
            raise ValueError(f"one policy reads the same state entries in every task, but task {other.name!r}'s "
                             f"{state!r} entries differ from {tasks[0].name!r}'s: train it with state='proprio'")
    columns = state_columns(demos.state_names, names, "the datasets' state")
    keys = tuple(demos.images) if cameras else ()
    if state == "proprio" and not keys:
        raise ValueError("a policy on proprioception alone cannot see where anything is: train it on datasets with "
                         "camera images (sb3-memret demos --render-backend cpu), or use state='full'")
    image_size = demos.images[keys[0]].shape[1] if keys else config.image_size
    unread = np.setdiff1d(np.arange(len(demos.state_names)), columns)
    if not keys or settings.perception_coef == 0:
        unread = unread[:0]
    perceived = tuple(demos.state_names[i] for i in unread)
    config = replace(config, task=tasks[0].name, tasks=tuple(t.name for t in tasks) if len(tasks) > 1 else (),
                     state_names=names, state_dim=len(names), image_features=keys, perceived_names=perceived,
                     image_size=image_size, training_prompts=tuple(sorted(demos.tasks)))
    tokenizer = tokenizer or PromptTokenizer()
    task_tokens, task_mask = tokenizer(demos.tasks)

    model = LearnedPolicy(config)
    config = model.config  # the trunk's checksum is filled in
    picked, hidden = demos.states[:, columns], demos.states[:, unread]
    labelled = np.ones(hidden.shape, dtype=bool) if demos.known is None else demos.known[:, unread]
    model.set_state_stats(torch.from_numpy(picked.mean(0)), torch.from_numpy(picked.std(0)))
    if perceived:
        model.set_perceived_stats(*(torch.from_numpy(x) for x in masked_stats(hidden, labelled)))
    targets, is_pad = demos.targets(config.chunk_len)
    is_val = np.isin(demos.episodes, validation_episodes(demos.episodes, settings.validation_fraction, rng))
    train_idx, val_idx = np.flatnonzero(~is_val), np.flatnonzero(is_val)
    if len(train_idx) == 0:
        raise ValueError("no training frames left after the validation split")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    pointed = pointer_targets(model, demos, ~is_val, tasks, out) if settings.pointer_hindsight > 0 else None
    hinted = pointed >= 0 if pointed is not None else None  # the prompts with a hindsight target

    states = torch.from_numpy(np.ascontiguousarray(picked))
    targets_t, is_pad_t, task_ids = torch.from_numpy(targets), torch.from_numpy(is_pad), torch.from_numpy(demos.task_ids)
    features = camera_inputs(model, demos.images, keys)
    from_pixels = model.trunk is None
    shifts = torch.Generator().manual_seed(settings.seed)
    labels = (torch.from_numpy(hidden) - model.perceived_mean) / model.perceived_std if perceived else None
    label_mask = torch.from_numpy(labelled)

    def losses_on(idx: np.ndarray) -> torch.Tensor:
        """(action chunk L1, perception MSE) on frames ``idx``; the perception term is 0 without perceived entries."""
        index = torch.from_numpy(idx)
        tid = task_ids[index]
        cams = [f[index].float() / 255.0 if from_pixels else f[index] for f in features]
        if from_pixels and model.training:
            cams = [shift_augment(c, settings.image_shift, shifts) for c in cams]
        prompt = model.encode_prompts(task_tokens, task_mask)[tid]
        vision = model.encode_cameras(cams, prompt)
        predicted = model.decode(states[index], prompt, vision)
        acting = chunk_loss(predicted, targets_t[index], is_pad_t[index])
        seen = (masked_mse(model.perceive(vision), labels[index], label_mask[index]) if perceived
                else acting.new_zeros(()))
        return torch.stack([acting, seen])

    def ambiguity() -> str:
        """The pointer's ``pointer_ambiguity`` over the training prompts, for the log ('' without a pointer)."""
        if model.pointer is None:
            return ""
        with torch.no_grad():
            weights = model.pointer.weights(model.encode_prompts(task_tokens, task_mask))
        return f"{float(pointer_ambiguity(weights)):.4f}"

    optimizer = torch.optim.AdamW(model.parameters(), lr=settings.learning_rate, weight_decay=settings.weight_decay)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: 0.5 * (1 + math.cos(math.pi * min(step, settings.steps) / settings.steps)))

    def hindsight_loss() -> torch.Tensor:
        """Cross-entropy of the training prompts' pointer weights against ``hindsight_objects`` (0 without)."""
        if pointed is None:
            return states.new_zeros(())
        pointing = model.pointer.weights(model.encode_prompts(task_tokens[hinted], task_mask[hinted]))
        return F.nll_loss(torch.log(pointing.clamp_min(1e-8)), pointed[hinted])

    weights = torch.tensor([1.0, settings.perception_coef])
    log_every = max(1, settings.steps // 50)
    started = time.monotonic()
    with open(out / LOG_FILE, "w", newline="") as f:
        log = csv.writer(f)
        log.writerow(["step", "train_loss", "val_loss", "val_perception_mse", "pointer_ambiguity", "seconds"])
        model.train()
        for step in range(1, settings.steps + 1):
            batch = rng.choice(train_idx, size=min(settings.batch_size, len(train_idx)), replace=False)
            losses = losses_on(batch)
            loss = (weights * losses).sum() + settings.pointer_hindsight * hindsight_loss()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            schedule.step()
            if on_step is not None:
                on_step(step, loss.item())
            if step % log_every == 0 or step == settings.steps:
                val = _validation_losses(model, losses_on, val_idx, settings.batch_size * 8)
                log.writerow([step, f"{losses[0].item():.5f}", *(["", ""] if val is None else
                                                                 [f"{val[0]:.5f}", f"{val[1]:.5f}" if perceived else ""]),
                              ambiguity(), f"{time.monotonic() - started:.1f}"])
                f.flush()
    model.eval()
    model.save_pretrained(out)
    return out


def pointer_targets(model: LearnedPolicy, demos: Demonstrations, training: np.ndarray, tasks: Sequence[Task],
                    out: Path) -> torch.Tensor:
    """``hindsight_objects`` of the ``training`` frames' episodes for the pointer's objects as a tensor, written to
    ``out/pointer_targets.json`` (each training prompt and the object it points at, null where its episodes
    disagree). A ValueError when the policy has no pointer or no prompt gets a target."""
    if model.pointer is None:
        raise ValueError("pointer_hindsight trains the pointer: finetune with pointer (--pointer)")
    objects = perceived_objects(model.config.perceived_names)[0]
    try:
        hands = {task.hand_position_names() for task in tasks}
    except NotImplementedError as err:
        raise ValueError(f"pointer hindsight reads where the hand ends: {err}") from err
    if len(hands) > 1:
        raise ValueError(f"pointer hindsight reads where the hand ends, but the tasks name it differently {hands}")
    hand = hands.pop()
    targets = hindsight_objects(demos, hand, objects, training)
    if (targets < 0).all():
        raise ValueError("pointer hindsight found no prompt whose episodes' hands mostly end nearest one object")
    table = {prompt: objects[t] if t >= 0 else None for prompt, t in zip(demos.tasks, targets)}
    (out / POINTER_TARGETS_FILE).write_text(json.dumps(table, indent=1))
    return torch.from_numpy(targets)


def tasks_template(tasks: Sequence[Task]) -> PromptTemplate:
    """The prompt contract of a policy trained on ``tasks``: every instruction and fact template of theirs, once."""
    templates = [task.prompt_template for task in tasks]
    return PromptTemplate(tuple(dict.fromkeys(i for t in templates for i in t.instructions)),
                          tuple(dict.fromkeys(f for t in templates for f in t.fact_templates)))


def masked_stats(values: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column, the mean and standard deviation of ``values`` over the rows ``mask`` marks (float32)."""
    count = np.maximum(mask.sum(0), 1)
    mean = np.where(mask, values, 0).sum(0) / count
    std = np.sqrt(np.where(mask, (values - mean) ** 2, 0).sum(0) / count)
    return mean.astype(np.float32), std.astype(np.float32)


def masked_mse(predicted: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The mean squared error over the entries ``mask`` marks (a frame's task's own perceived entries)."""
    weight = mask.to(predicted.dtype)
    return ((predicted - target) ** 2 * weight).sum() / weight.sum().clamp_min(1.0)


@torch.no_grad()
def _validation_losses(model: LearnedPolicy, losses_on: Callable[[np.ndarray], torch.Tensor], idx: np.ndarray,
                       batch: int) -> list[float] | None:
    """The mean of ``losses_on`` over the validation frames ``idx`` (None without any)."""
    if len(idx) == 0:
        return None
    model.eval()
    total = sum(losses_on(idx[i: i + batch]) * len(idx[i: i + batch]) for i in range(0, len(idx), batch))
    model.train()
    return (total / len(idx)).tolist()


def read_log(out: str | Path) -> list[dict[str, str]]:
    """The rows of a finetune run's ``train_log.csv``."""
    with open(Path(out) / LOG_FILE) as f:
        return list(csv.DictReader(f))


__all__ = ["Demonstrations", "FinetuneSettings", "STATE_CHOICES", "finetune", "has_cameras", "hindsight_objects",
           "load_demonstrations", "load_task_demonstrations", "masked_mse", "masked_stats", "pointer_targets",
           "read_log", "state_names_for", "tasks_template", "validation_episodes"]
