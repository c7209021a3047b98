"""Train the project's learned controller from demonstration datasets (behaviour cloning of action chunks).

Every frame of every episode is a sample: its state (and camera images, when the datasets have
them), its prompt as frozen MiniLM token features, and as target the expert's labels for the
next ``chunk_len`` frames of the same episode (steps past the episode's end are padding, left
out of the L1 loss, as lerobot's ``action_is_pad``). Several datasets (the expert's, then DAgger
rounds) train one policy together.
"""

from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from sb3_memret.controllers.learned.configuration import LearnedPolicyConfig
from sb3_memret.controllers.learned.modeling import LearnedPolicy, chunk_loss
from sb3_memret.controllers.learned.processing import PromptTokenizer, image_tensor
from sb3_memret.controllers.observation import ACTION_DIM, ACTION_KEY, IMAGE_KEYS, STATE_DIM, STATE_KEY
from sb3_memret.prompts import INSTRUCTION_TEMPLATE, PromptTemplate, parse_prompt

LOG_FILE = "train_log.csv"


@dataclass(frozen=True)
class FinetuneSettings:
    """Optimisation settings of ``finetune``."""

    steps: int = 20_000
    batch_size: int = 256
    learning_rate: float = 1e-3
    weight_decay: float = 1e-4
    validation_fraction: float = 0.1
    seed: int = 0

    def __post_init__(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or self.learning_rate <= 0:
            raise ValueError(f"steps and batch_size must be >= 1 and learning_rate > 0: {self}")
        if not 0 <= self.validation_fraction < 1:
            raise ValueError(f"validation_fraction must lie in [0, 1), got {self.validation_fraction}")


@dataclass
class Demonstrations:
    """All frames of one or more datasets as arrays, with each frame's chunk of target indices."""

    states: np.ndarray  # (N, 19) float32
    actions: np.ndarray  # (N, 7) float32
    episodes: np.ndarray  # (N,) a global episode id
    task_ids: np.ndarray  # (N,) index into tasks
    tasks: list[str]
    images: dict[str, np.ndarray]  # feature -> (N, 3, S, S) uint8, empty for state-only data

    def chunk_indices(self, chunk_len: int) -> tuple[np.ndarray, np.ndarray]:
        """(N, chunk_len) frame indices of each frame's target chunk and the mask of steps past its episode."""
        n = len(self.actions)
        ends = np.zeros(n, dtype=np.int64)
        boundaries = np.flatnonzero(np.diff(self.episodes)) + 1
        starts, stops = np.r_[0, boundaries], np.r_[boundaries, n]
        for a, b in zip(starts, stops):
            ends[a:b] = b - 1
        raw = np.arange(n)[:, None] + np.arange(chunk_len)[None, :]
        return np.minimum(raw, ends[:, None]), raw > ends[:, None]


def load_demonstrations(roots: Sequence[str | Path], image_size: int | None = None) -> Demonstrations:
    """Read LeRobotDatasets written by ``sb3-memret demos`` (lerobot's reader), checking their features."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if not roots:
        raise ValueError("no dataset given")
    parts, tasks, offset, image_keys = [], [], 0, None
    for root in roots:
        root = Path(root)
        if not (root / "meta" / "info.json").is_file():
            raise FileNotFoundError(f"{root} is not a LeRobotDataset (no meta/info.json); write one with "
                                    "`sb3-memret demos --out DIR`")
        dataset = LeRobotDataset(f"local/{root.name}", root=root, video_backend="pyav")  # no videos to decode
        features = dataset.meta.features
        _check_feature(features, STATE_KEY, (STATE_DIM,), root)
        _check_feature(features, ACTION_KEY, (ACTION_DIM,), root)
        keys = tuple(k for k in IMAGE_KEYS if k in features)
        if image_keys is not None and keys != image_keys:
            raise ValueError(f"{root} has cameras {list(keys)} but an earlier dataset has {list(image_keys)}; "
                             "train on datasets recorded with the same render backend")
        image_keys = keys
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
            "images": {k: _load_images(dataset, k, image_size) for k in keys},
        }
        offset = int(part["episodes"].max()) + 1
        parts.append(part)
    return Demonstrations(
        states=np.concatenate([p["states"] for p in parts]),
        actions=np.concatenate([p["actions"] for p in parts]),
        episodes=np.concatenate([p["episodes"] for p in parts]),
        task_ids=np.concatenate([p["task_ids"] for p in parts]),
        tasks=tasks,
        images={k: np.concatenate([p["images"][k] for p in parts]) for k in (image_keys or ())},
    )


def _task_id(task: str, tasks: list[str]) -> int:
    if task not in tasks:
        tasks.append(task)
    return tasks.index(task)


def _check_feature(features: dict, key: str, shape: tuple[int, ...], root: Path) -> None:
    if key not in features or tuple(features[key]["shape"]) != shape:
        found = features.get(key, {}).get("shape")
        raise ValueError(f"{root}: feature {key!r} has shape {found}, expected {shape} (the layout of "
                         "sb3_memret.controllers.observation)")


def _load_images(dataset, key: str, image_size: int | None) -> np.ndarray:
    """All frames of one camera, resized to the policy's input size, as (N, 3, S, S) uint8."""
    if image_size is None:
        raise ValueError("image_size is needed to load a dataset with camera images")
    frames = []
    for i in range(len(dataset)):
        image = torch.as_tensor(np.asarray(dataset.hf_dataset[i][key]))[None]
        frames.append((image_tensor(image, image_size)[0] * 255).round().to(torch.uint8).numpy())
    return np.stack(frames)


def training_instructions(tasks: Sequence[str], fact_templates: Sequence[str]) -> tuple[str, ...]:
    """The instructions a policy trained on ``tasks`` accepts: the one instruction they hold, or
    ``pick out the {entity}.`` when they name several objects (the policy then takes any object word)."""
    template = PromptTemplate((INSTRUCTION_TEMPLATE,), tuple(fact_templates))
    instructions = sorted({parse_prompt(task, template).instruction for task in tasks})
    return (INSTRUCTION_TEMPLATE,) if len(instructions) > 1 else tuple(instructions)


def finetune(
    datasets: Sequence[str | Path],
    out: str | Path,
    config: LearnedPolicyConfig | None = None,
    settings: FinetuneSettings | None = None,
    tokenizer: PromptTokenizer | None = None,
    on_step: Callable[[int, float], None] | None = None,
) -> Path:
    """Train a LearnedPolicy on ``datasets`` and save it to ``out`` (``save_pretrained``); returns ``out``."""
    settings = settings or FinetuneSettings()
    config = config or LearnedPolicyConfig()
    torch.manual_seed(settings.seed)
    rng = np.random.default_rng(settings.seed)
    demos = load_demonstrations(datasets, config.image_size)
    config = replace(config, instructions=training_instructions(demos.tasks, config.fact_templates))
    for task in demos.tasks:
        parse_prompt(task, config.prompt_template)  # a dataset prompt outside the contract is refused
    config = replace(config, image_features=tuple(demos.images), training_prompts=tuple(sorted(demos.tasks)))
    tokenizer = tokenizer or PromptTokenizer()
    task_tokens, task_mask = tokenizer(demos.tasks)

    model = LearnedPolicy(config)
    model.set_state_stats(torch.from_numpy(demos.states.mean(0)), torch.from_numpy(demos.states.std(0)))
    targets, is_pad = demos.chunk_indices(config.chunk_len)
    episode_ids = np.unique(demos.episodes)
    n_val = int(round(len(episode_ids) * settings.validation_fraction))
    val_episodes = rng.choice(episode_ids, size=n_val, replace=False) if n_val else np.array([], dtype=np.int64)
    is_val = np.isin(demos.episodes, val_episodes)
    train_idx, val_idx = np.flatnonzero(~is_val), np.flatnonzero(is_val)
    if len(train_idx) == 0:
        raise ValueError("no training frames left after the validation split")

    states, actions = torch.from_numpy(demos.states), torch.from_numpy(demos.actions)
    images = {k: torch.from_numpy(v) for k, v in demos.images.items()}
    targets_t, is_pad_t, task_ids = torch.from_numpy(targets), torch.from_numpy(is_pad), torch.from_numpy(demos.task_ids)

    def loss_on(idx: np.ndarray) -> torch.Tensor:
        index = torch.from_numpy(idx)
        tid = task_ids[index]
        cams = [images[k][index].float() / 255.0 for k in config.image_features]
        predicted = model(states[index], model.encode_prompts(task_tokens, task_mask)[tid], cams)
        return chunk_loss(predicted, actions[targets_t[index]], is_pad_t[index])

    optimizer = torch.optim.AdamW(model.parameters(), lr=settings.learning_rate, weight_decay=settings.weight_decay)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: 0.5 * (1 + math.cos(math.pi * min(step, settings.steps) / settings.steps)))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    log_every = max(1, settings.steps // 50)
    started = time.monotonic()
    with open(out / LOG_FILE, "w", newline="") as f:
        log = csv.writer(f)
        log.writerow(["step", "train_loss", "val_loss", "seconds"])
        model.train()
        for step in range(1, settings.steps + 1):
            batch = rng.choice(train_idx, size=min(settings.batch_size, len(train_idx)), replace=False)
            loss = loss_on(batch)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            schedule.step()
            if on_step is not None:
                on_step(step, loss.item())
            if step % log_every == 0 or step == settings.steps:
                val = _validation_loss(model, loss_on, val_idx, settings.batch_size * 8)
                log.writerow([step, f"{loss.item():.5f}", "" if val is None else f"{val:.5f}",
                              f"{time.monotonic() - started:.1f}"])
                f.flush()
    model.eval()
    model.save_pretrained(out)
    return out


@torch.no_grad()
def _validation_loss(model: LearnedPolicy, loss_on: Callable[[np.ndarray], torch.Tensor], idx: np.ndarray,
                     batch: int) -> float | None:
    if len(idx) == 0:
        return None
    model.eval()
    total = sum(float(loss_on(idx[i: i + batch])) * len(idx[i: i + batch]) for i in range(0, len(idx), batch))
    model.train()
    return total / len(idx)


def read_log(out: str | Path) -> list[dict[str, str]]:
    """The rows of a finetune run's ``train_log.csv``."""
    with open(Path(out) / LOG_FILE) as f:
        return list(csv.DictReader(f))


__all__ = ["Demonstrations", "FinetuneSettings", "finetune", "load_demonstrations", "read_log"]
