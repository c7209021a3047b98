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
layout: all of it, with ``state="proprio"`` only what a robot reads of itself, or with ``state="harness"`` the
seven numbers MIKASA's harness gives a policy (``harness_proprio``: the hand's xyz and roll-pitch-yaw, the gripper),
derived from the layout's hand pose and finger joints; the entries it does not read beyond the robot's own
(the simulator's detection, drawer openings) become the policy's ``perceived_names``: its
perception head estimates them from the images, trained on the simulator's labels (``perception_coef``),
and its action head reads the estimates. (Measured here: frozen EfficientNet-Lite0 features locate the
cube within 0.8 cm and its yaw within 7 degrees, ``lab/2026-11-26-the-learned-controllers/probe_camera_features.py``, yet behaviour
cloning alone did not learn to use them.)
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence, TextIO

import numpy as np
import torch

from sb3_memret.common.cache import write_atomically
from sb3_memret.controllers.harness_proprio import HARNESS_PROPRIO_NAMES, SOURCE_NAMES
from sb3_memret.controllers.learned.configuration import LearnedPolicyConfig, perceived_objects
from sb3_memret.controllers.learned.modeling import LearnedPolicy, TrainingBatch, pointer_ambiguity
from sb3_memret.controllers.learned.processing import (LearnedPolicyProcessor, PromptTokenizer, channels_first,
                                                       state_columns)
from sb3_memret.controllers.learned.vision import shift_augment
from sb3_memret.controllers.prompts import PromptTemplate, parse_prompt
from sb3_memret.stage1.datasets import (CameraFrames, Demonstrations, dataset_prompts, hindsight_objects,
                                        load_demonstrations, load_task_demonstrations, validation_episodes)
from sb3_memret.stage1.feature_cache import cached_features
from sb3_memret.stage1.sampling import FrameSampler
from sb3_memret.tasks import Task, make_task

LOG_FILE = "train_log.csv"
LOG_HEADER = ["step", "train_loss", "train_perception_mse", "val_loss", "val_perception_mse", "pointer_ambiguity",
              "seconds"]
STATE_FILE = "training_state.pt"  # an unfinished finetune at its last logged step, removed once the policy is saved
POINTER_TARGETS_FILE = "pointer_targets.json"  # finetune's hindsight target of each training prompt, for reading
# the whole state layout, what a robot reads of itself, or the seven numbers MIKASA's harness gives a policy
STATE_CHOICES = ("full", "proprio", "harness")
PRIORITY_WITHIN = ("split", "task")  # FinetuneSettings.priority_within
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
    # how batches are drawn (``FrameSampler``): 0 uniformly; p > 0 each frame with probability proportional to
    # (its last action error + the mean error) ** p, so that a rare phase the policy gets wrong is drawn more often
    priority: float = 0.0
    # where the errors rank frames (``FrameSampler``'s strata): "split", across every training frame; "task", within
    # each task's frames of a multi-task finetune, each task keeping its share of the draws
    priority_within: str = "split"

    def __post_init__(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or self.learning_rate <= 0 or min(
                self.image_shift, self.perception_coef, self.pointer_hindsight, self.priority) < 0:
            raise ValueError(f"steps and batch_size must be >= 1, learning_rate > 0, image_shift, perception_coef, "
                             f"pointer_hindsight and priority >= 0: {self}")
        if not 0 <= self.validation_fraction < 1:
            raise ValueError(f"validation_fraction must lie in [0, 1), got {self.validation_fraction}")
        if self.priority_within not in PRIORITY_WITHIN:
            raise ValueError(f"priority_within must be one of {list(PRIORITY_WITHIN)}, got {self.priority_within!r}")


def training_instructions(prompts: Sequence[str], instructions: Sequence[str], fact_templates: Sequence[str],
                          fields: tuple[tuple[str, str], ...] = ()) -> tuple[str, ...]:
    """The instructions a policy trained on ``prompts`` accepts: the one instruction they hold, or
    the templates ``instructions`` when they hold several (``pick out the {entity}.``: any object word)."""
    template = PromptTemplate(tuple(instructions), tuple(fact_templates), fields)
    held = sorted({parse_prompt(prompt, template).instruction for prompt in prompts})
    return tuple(instructions) if len(held) > 1 else tuple(held)


def state_names_for(task: Task, state: str) -> tuple[str, ...]:
    """The state entries a policy reads: ``full`` (the task's layout), ``proprio`` (what a robot reads of itself) or
    ``harness`` (MIKASA's harness proprioception, derived from the layout's hand pose and fingers)."""
    if state not in STATE_CHOICES:
        raise ValueError(f"unknown state {state!r}; expected one of {list(STATE_CHOICES)}")
    if state == "harness":
        missing = [name for name in SOURCE_NAMES if name not in task.state_names()]
        if missing:
            raise ValueError(f"task {task.name!r}'s state layout has no {missing}: state='harness' is MIKASA's "
                             "harness proprioception, derived from the Panda's hand pose and finger joints")
        return HARNESS_PROPRIO_NAMES
    return task.state_names() if state == "full" else task.proprio_names()


def camera_inputs(model: LearnedPolicy, processor: LearnedPolicyProcessor,
                  images: Mapping[str, CameraFrames | np.ndarray], keys: Sequence[str],
                  cache: bool = True) -> list[torch.Tensor]:
    """What the policy's camera heads read for every frame: a frozen trunk's features of the processor's images
    (computed in batches a dataset at a time, kept as float16; with ``cache``, per dataset through
    ``cached_features``), or the uint8 images themselves (channels first) for encoders trained from pixels."""
    def blocks(key: str) -> Iterable[np.ndarray]:
        frames = images[key]
        return frames.blocks() if isinstance(frames, CameraFrames) else [frames]

    if model.trunk is None:
        return [channels_first(np.concatenate([*blocks(key)])) for key in keys]

    def compute(frames: np.ndarray) -> torch.Tensor:
        x = channels_first(frames)
        return torch.cat([model.trunk(processor.camera(x[i: i + FEATURE_BATCH])).half()
                          for i in range(0, len(x), FEATURE_BATCH)]).contiguous()  # as the cache reads them back

    def features(block: np.ndarray) -> torch.Tensor:
        return cached_features(model.trunk, block, (len(block),), compute) if cache else compute(block)

    def stacked(key: str) -> torch.Tensor:  # filled block by block: joined, the features would be held twice
        out, start = None, 0
        for part in map(features, blocks(key)):
            if out is None:
                out = torch.empty((len(images[key]), *part.shape[1:]), dtype=part.dtype)
            out[start: start + len(part)] = part
            start += len(part)
        return out if out is not None else torch.empty(0)

    return [stacked(key) for key in keys]


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
    cache_features: bool = True,
    resume: bool = False,
) -> Path:
    """Train a LearnedPolicy on ``datasets`` of ``task``, or on a mapping from each of several tasks to its datasets
    (one multi-task policy), and save it to ``out`` (``save_pretrained``); returns ``out``. ``state`` picks the state
    entries it reads (``full``, ``proprio`` or ``harness``); ``cameras=False`` leaves the datasets' camera images out;
    ``cache_features`` keeps a frozen trunk's features of each dataset on disk for the next finetune
    (``feature_cache``). The prompt contract is the tasks' own templates (together), or ``config``'s. At every logged
    step the run's state is kept in ``out/training_state.pt``; ``resume`` goes on from it, to the same weights as a
    run never stopped, on the same data and settings only."""
    settings = settings or FinetuneSettings()
    out = Path(out)
    check_unfinished(out, resume)
    check_dataset_prompts(datasets, task, config)
    tasks, demos = _load(datasets, task)
    if state == "harness":
        demos = demos.with_harness_proprio()
    config = config or default_config(tasks)
    torch.manual_seed(settings.seed)
    rng = np.random.default_rng(settings.seed)
    config, reads = policy_config(config, tasks, demos, state, cameras, settings.perception_coef)
    tokenizer = tokenizer or PromptTokenizer()
    tokens = tokenizer(demos.tasks)
    model = LearnedPolicy(config)
    processor = LearnedPolicyProcessor(model.config, tokenizer=tokenizer)
    data = DemoTensors.build(model, processor, demos, reads, tokens, rng, settings, tasks, out, cache_features)
    _train(model, data, settings, out, rng, resume, on_step)
    model.eval()
    model.save_pretrained(out)
    (out / STATE_FILE).unlink(missing_ok=True)
    return out


def check_unfinished(out: Path, resume: bool) -> None:
    """``resume`` needs an unfinished finetune in ``out``; a fresh one refuses a folder that holds one."""
    if resume and not (out / STATE_FILE).is_file():
        raise FileNotFoundError(f"nothing to resume: {out} holds no unfinished finetune ({STATE_FILE})")
    if not resume and (out / STATE_FILE).is_file():
        raise FileExistsError(f"{out} holds an unfinished finetune ({STATE_FILE}): resume it (--resume) or delete "
                              "the folder")


def with_contract(config: LearnedPolicyConfig,
                  tasks: Sequence[Task]) -> tuple[LearnedPolicyConfig, tuple[tuple[str, str], ...]]:
    """``config`` with a prompt contract (a config without one takes its tasks' templates) and the tasks' field
    patterns."""
    template = tasks_template(tasks)
    if not config.instructions:
        config = replace(config, instructions=template.instructions,
                         fact_templates=config.fact_templates or template.fact_templates)
    return config, template.fields


def check_dataset_prompts(datasets: Sequence[str | Path] | Mapping[str | Task, Sequence[str | Path]],
                          task: str | Task | None, config: LearnedPolicyConfig | None) -> None:
    """Refuse, before any frame is read, a dataset prompt outside the contract the policy would train under (the
    config's, else its tasks' own templates together), naming the prompt and the accepted forms."""
    per_task = datasets if isinstance(datasets, Mapping) else {task: datasets} if task is not None else {}
    tasks = [make_task(name) for name in per_task]
    if not tasks:
        return  # _load names what is missing
    config, fields = with_contract(config or default_config(tasks), tasks)
    contract = config.prompt_template(fields)
    for prompt in dataset_prompts([root for roots in per_task.values() for root in roots]):
        parse_prompt(prompt, contract)


def _load(datasets: Sequence[str | Path] | Mapping[str | Task, Sequence[str | Path]],
          task: str | Task | None) -> tuple[list[Task], Demonstrations]:
    """The tasks and their demonstrations: one task's datasets (``task`` required), or a mapping from each task to
    its datasets."""
    if isinstance(datasets, Mapping):
        if task is not None:
            raise ValueError(f"datasets given per task name their tasks; task {task!r} is not needed")
        demos, tasks = load_task_demonstrations(datasets)
        return tasks, demos
    if task is None:
        raise ValueError("datasets of one task need that task (task=...), or give a mapping from each task to its "
                         "datasets")
    tasks = [make_task(task)]
    return tasks, load_demonstrations(datasets, tasks[0])


def default_config(tasks: Sequence[Task]) -> LearnedPolicyConfig:
    """A policy with the default options whose prompt contract is the tasks' own templates."""
    template = tasks_template(tasks)
    return LearnedPolicyConfig(fact_templates=template.fact_templates, instructions=template.instructions)


@dataclass(frozen=True)
class Reads:
    """Where a policy's inputs lie in the demonstrations: the state columns it reads, the columns its perception
    head estimates instead, and the camera features."""

    columns: np.ndarray
    unread: np.ndarray
    cameras: tuple[str, ...]


def policy_config(config: LearnedPolicyConfig, tasks: Sequence[Task], demos: Demonstrations, state: str,
                  cameras: bool, perception_coef: float) -> tuple[LearnedPolicyConfig, Reads]:
    """``config`` completed from the demonstrations (the instructions and prompts they hold, the state entries the
    policy reads, the cameras, the perceived entries, the robot), and where those inputs lie in them; refused with a
    ValueError naming what does not fit (a prompt outside the contract, tasks whose state entries differ)."""
    config, fields = with_contract(config, tasks)
    config = replace(config, instructions=training_instructions(demos.tasks, config.instructions,
                                                                config.fact_templates, fields))
    for prompt in demos.tasks:
        parse_prompt(prompt, config.prompt_template(fields))  # a dataset prompt outside the contract is refused
    names = state_names_for(tasks[0], state)
    for other in tasks[1:]:
        if state_names_for(other, state) != names:
            raise ValueError(f"one policy reads the same state entries in every task, but task {other.name!r}'s "
                             f"{state!r} entries differ from {tasks[0].name!r}'s: train it with state='proprio'")
    columns = state_columns(demos.state_names, names, "the datasets' state")
    keys = tuple(demos.images) if cameras else ()
    if state != "full" and not keys:
        raise ValueError("a policy on proprioception alone cannot see where anything is: train it on datasets with "
                         "camera images (sb3-memret demos --render-backend cpu), or use state='full'")
    own = set(tasks[0].proprio_names()) | set(HARNESS_PROPRIO_NAMES)  # the robot's own readings: never perceived
    unread = np.array([i for i, name in enumerate(demos.state_names) if i not in columns and name not in own],
                      dtype=np.int64)
    if not keys or perception_coef == 0:
        unread = unread[:0]
    config = replace(config, task=tasks[0].name, tasks=tuple(t.name for t in tasks) if len(tasks) > 1 else (),
                     state_names=names, state_dim=len(names), image_features=keys,
                     perceived_names=tuple(demos.state_names[i] for i in unread),
                     image_size=demos.images[keys[0]].shape[1] if keys else config.image_size,
                     training_prompts=tuple(sorted(demos.tasks)), robot=demos.robot if keys else None)
    return config, Reads(columns, unread, keys)


@dataclass
class DemoTensors:
    """Every demonstration frame as the policy trains on it, split into training and validation episodes; ``batch``
    hands ``LearnedPolicy.losses`` the frames it is given. Inputs go through the acting side's
    ``LearnedPolicyProcessor`` (state columns by name, camera scaling), labels come from the datasets."""

    processor: LearnedPolicyProcessor
    states: torch.Tensor  # (N, state_dim)
    cameras: list[torch.Tensor]  # per camera: a frozen trunk's float16 features, or the uint8 images (N, 3, S, S)
    from_pixels: bool
    tokens: torch.Tensor  # (P, T, token_dim): every training prompt
    token_mask: torch.Tensor
    prompt_ids: torch.Tensor  # (N,) each frame's prompt
    targets: torch.Tensor
    is_pad: torch.Tensor
    perceived: torch.Tensor | None  # (N, K) normalised labels of the perceived entries
    perceived_mask: torch.Tensor
    pointed: torch.Tensor | None  # (P,) each prompt's hindsight object, -1 where none
    train_idx: np.ndarray
    val_idx: np.ndarray
    strata: np.ndarray | None  # (len(train_idx),) each training frame's task where draws keep each task's share
    spans: tuple[int, ...]  # the datasets' frame counts
    image_shift: int
    shifts: torch.Generator  # the random shifts of images from pixels

    @classmethod
    def build(cls, model: LearnedPolicy, processor: LearnedPolicyProcessor, demos: Demonstrations, reads: Reads,
              tokens: tuple[torch.Tensor, torch.Tensor], rng: np.random.Generator, settings: FinetuneSettings,
              tasks: Sequence[Task], out: Path, cache_features: bool) -> "DemoTensors":
        """The frames of ``demos`` for ``model`` through its ``processor`` (the model's state and perception
        statistics are set from them; ``tokens``: the training prompts' features); the validation episodes are drawn
        with ``rng``. With hindsight, ``out`` gets the prompts' pointer targets."""
        config = model.config
        picked, hidden = demos.states[:, reads.columns], demos.states[:, reads.unread]
        labelled = np.ones(hidden.shape, dtype=bool) if demos.known is None else demos.known[:, reads.unread]
        model.set_state_stats(torch.from_numpy(picked.mean(0)), torch.from_numpy(picked.std(0)))
        if config.perceived_names:
            model.set_perceived_stats(*(torch.from_numpy(x) for x in masked_stats(hidden, labelled)))
        targets, is_pad = demos.targets(config.chunk_len)
        is_val = np.isin(demos.episodes, validation_episodes(demos.episodes, settings.validation_fraction, rng))
        train_idx, val_idx = np.flatnonzero(~is_val), np.flatnonzero(is_val)
        if len(train_idx) == 0:
            raise ValueError("no training frames left after the validation split")
        out.mkdir(parents=True, exist_ok=True)
        pointed = pointer_targets(model, demos, ~is_val, tasks, out) if settings.pointer_hindsight > 0 else None
        perceived = ((torch.from_numpy(hidden) - model.perceived_mean) / model.perceived_std
                     if config.perceived_names else None)
        return cls(processor, processor.state(demos.states, reads.columns),
                   camera_inputs(model, processor, demos.images, reads.cameras, cache_features),
                   model.trunk is None, *tokens, torch.from_numpy(demos.task_ids), torch.from_numpy(targets),
                   torch.from_numpy(is_pad), perceived, torch.from_numpy(labelled), pointed, train_idx, val_idx,
                   demos.sources[train_idx] if settings.priority_within == "task" and demos.sources is not None
                   else None, tuple(int(n) for n in demos.spans), settings.image_shift,
                   torch.Generator().manual_seed(settings.seed))

    def batch(self, idx: np.ndarray, augment: bool) -> TrainingBatch:
        """Frames ``idx`` (images from pixels shifted at random with ``augment``), each distinct prompt once: a
        progress task has hundreds of training prompts and a batch a fraction of them."""
        index = torch.from_numpy(idx)
        cams = [self.processor.camera(f[index]) if self.from_pixels else f[index] for f in self.cameras]
        if self.from_pixels and augment:
            cams = [shift_augment(c, self.image_shift, self.shifts) for c in cams]
        used, which = torch.unique(self.prompt_ids[index], return_inverse=True)
        return TrainingBatch(self.states[index], cams, self.tokens[used], self.token_mask[used], which,
                             self.targets[index], self.is_pad[index],
                             None if self.perceived is None else self.perceived[index], self.perceived_mask[index],
                             None if self.pointed is None else self.pointed[used])


def _train(model: LearnedPolicy, data: DemoTensors, settings: FinetuneSettings, out: Path, rng: np.random.Generator,
           resume: bool, on_step: Callable[[int, float], None] | None) -> None:
    """AdamW on the weighted sum of ``LearnedPolicy.losses`` over random training batches, the learning rate on a
    cosine from ``settings.learning_rate`` to 0; every ``steps // 50`` steps a row of ``train_log.csv`` and the run's
    state (``resume`` goes on from the last one)."""
    optimizer = torch.optim.AdamW(model.parameters(), lr=settings.learning_rate, weight_decay=settings.weight_decay)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: 0.5 * (1 + math.cos(math.pi * min(step, settings.steps) / settings.steps)))
    weights = torch.tensor([1.0, settings.perception_coef, settings.pointer_hindsight])
    losses_on = lambda idx: model.losses(data.batch(idx, augment=model.training))[0]  # noqa: E731
    sampler = FrameSampler(data.train_idx, settings.priority, data.strata)
    perceived = data.perceived is not None
    log_every = max(1, settings.steps // 50)
    run = _run_fingerprint(model.config, settings, data.spans, len(data.train_idx))
    state_path, done, elapsed = out / STATE_FILE, 0, 0.0
    if resume:
        done, elapsed = _load_training_state(state_path, run, model, optimizer, schedule, rng, data.shifts, sampler)
    started = time.monotonic() - elapsed
    with _open_log(out / LOG_FILE, done) as f:
        log = csv.writer(f)
        model.train()
        for step in range(done + 1, settings.steps + 1):
            batch = sampler.draw(rng, settings.batch_size)
            losses, errors = model.losses(data.batch(batch, augment=True))
            sampler.update(batch, errors.numpy())
            loss = (weights * losses).sum()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            schedule.step()
            if on_step is not None:
                on_step(step, loss.item())
            if step % log_every == 0 or step == settings.steps:
                val = _validation_losses(model, losses_on, data.val_idx, settings.batch_size * 8)
                held = ["", ""] if val is None else [f"{val[0]:.5f}", f"{val[1]:.5f}" if perceived else ""]
                log.writerow([step, f"{losses[0].item():.5f}", f"{losses[1].item():.5f}" if perceived else "", *held,
                              _ambiguity(model, data), f"{time.monotonic() - started:.1f}"])
                f.flush()
                if step < settings.steps:
                    _save_training_state(state_path, run, step, time.monotonic() - started, model, optimizer,
                                         schedule, rng, data.shifts, sampler)


def _ambiguity(model: LearnedPolicy, data: DemoTensors) -> str:
    """The pointer's ``pointer_ambiguity`` over the training prompts, for the log ('' without a pointer)."""
    if model.pointer is None:
        return ""
    with torch.no_grad():
        weights = model.pointer.weights(model.encode_prompts(data.tokens, data.token_mask))
    return f"{float(pointer_ambiguity(weights)):.4f}"


def _open_log(path: Path, done: int) -> TextIO:
    """``train_log.csv`` opened for the rows after step ``done``: a new log, or a resumed run's rows up to ``done``
    (rows logged after its last kept state are dropped, since they are trained again)."""
    kept = [row for row in read_log(path.parent) if int(row["step"]) <= done] if done else []
    f = open(path, "w", newline="")
    writer = csv.DictWriter(f, LOG_HEADER)
    writer.writeheader()
    writer.writerows(kept)
    f.flush()
    return f


def _run_fingerprint(config: LearnedPolicyConfig, settings: FinetuneSettings, spans: Sequence[int],
                     n_train: int) -> str:
    """SHA-256 of what a resumed finetune must share with the run it goes on from: the policy's config, the
    settings, the datasets' frame counts and the training split's size."""
    facts = {"config": asdict(config), "settings": asdict(settings), "spans": [int(n) for n in spans],
             "train_frames": n_train}
    return hashlib.sha256(json.dumps(facts, sort_keys=True, default=str).encode()).hexdigest()


def _save_training_state(path: Path, run: str, step: int, elapsed: float, model: LearnedPolicy,
                         optimizer: torch.optim.Optimizer, schedule: torch.optim.lr_scheduler.LRScheduler,
                         rng: np.random.Generator, shifts: torch.Generator, sampler: FrameSampler) -> None:
    """Write the run's state at ``step`` atomically (a run stopped while writing keeps the previous one)."""
    state = {"run": run, "step": step, "elapsed": elapsed, "model": model.state_dict(),
             "optimizer": optimizer.state_dict(), "schedule": schedule.state_dict(),
             "numpy_rng": json.dumps(rng.bit_generator.state), "torch_rng": torch.get_rng_state(),
             "shifts": shifts.get_state(), "frame_errors": torch.from_numpy(sampler.state())}
    write_atomically(path, lambda f: torch.save(state, f))


def _load_training_state(path: Path, run: str, model: LearnedPolicy, optimizer: torch.optim.Optimizer,
                         schedule: torch.optim.lr_scheduler.LRScheduler, rng: np.random.Generator,
                         shifts: torch.Generator, sampler: FrameSampler) -> tuple[int, float]:
    """Restore a run's state from ``path`` into the objects given; (its step, seconds trained). A ValueError when
    it was written by a run on other data or settings."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several kinds for a truncated or foreign file
        raise ValueError(f"{path} cannot be read as a finetune's state ({type(err).__name__}): delete the folder to "
                         "start afresh") from err
    if not isinstance(state, dict) or state.get("run") != run:
        raise ValueError(f"{path} was written by a finetune on other datasets, settings or policy options; resume "
                         "with the same ones, or delete the folder to start afresh")
    model.load_state_dict(state["model"])
    optimizer.load_state_dict(state["optimizer"])
    schedule.load_state_dict(state["schedule"])
    rng.bit_generator.state = json.loads(state["numpy_rng"])
    torch.set_rng_state(state["torch_rng"])
    shifts.set_state(state["shifts"])
    sampler.load_state(state["frame_errors"].numpy())
    return int(state["step"]), float(state["elapsed"])


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
    """The prompt contract a policy trained on ``tasks`` may take: every instruction template of their
    demonstrations (``Task.instruction_templates``) and every fact template of theirs, once; the finetune keeps the
    instructions its datasets hold (``training_instructions``)."""
    facts = PromptTemplate.merged([task.prompt_template for task in tasks])  # a field worded two ways takes either
    return replace(facts, instructions=tuple(dict.fromkeys(i for task in tasks for i in task.instruction_templates)))


def masked_stats(values: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column, the mean and standard deviation of ``values`` over the rows ``mask`` marks (float32)."""
    count = np.maximum(mask.sum(0), 1)
    mean = np.where(mask, values, 0).sum(0) / count
    std = np.sqrt(np.where(mask, (values - mean) ** 2, 0).sum(0) / count)
    return mean.astype(np.float32), std.astype(np.float32)


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


__all__ = ["DemoTensors", "FinetuneSettings", "PRIORITY_WITHIN", "Reads", "STATE_CHOICES", "STATE_FILE",
           "check_unfinished", "default_config", "finetune", "masked_stats", "pointer_targets", "policy_config",
           "read_log", "state_names_for", "tasks_template"]
