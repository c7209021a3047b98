"""Finetune lerobot's π0.5 (``PI05Policy``) with a LoRA adapter on a demonstration dataset (for users with π0.5
weights and a GPU).

The pretrained weights stay frozen and are copied unchanged; only LoRA factors on the modules lerobot's own
PEFT support targets for PI05 (``PI05Policy._get_default_peft_targets``) are trained, on lerobot's
flow-matching loss (``PI05Policy.forward``) over action chunks read by lerobot's ``LeRobotDataset``, with the
processors' normalisation stats replaced by the dataset's, as ``lerobot-train`` does when it finetunes a
pretrained policy. ``out`` then holds what ``LeRobotPi05Controller`` loads, i.e. the controller spec
``lerobot:OUT/checkpoint?adapter=OUT/adapter&tokenizer=TOK``.
"""

from __future__ import annotations

import csv
import math
import shutil
from pathlib import Path
from typing import Any, Callable, Iterator

import torch

from sb3_memret.controllers.lerobot_pi05 import (WEIGHTS_FILE, check_features, load_checked_policy, load_pi05_config,
                                                 local_folder)
from sb3_memret.controllers.observation import ACTION_KEY, IMAGE_KEYS
from sb3_memret.controllers.prompts import PromptTemplate, parse_prompt

CHECKPOINT_DIR, ADAPTER_DIR, LOG_FILE = "checkpoint", "adapter", "train_log.csv"


def finetune_pi05(
    dataset_root: str | Path,
    pretrained: str | Path,
    out: str | Path,
    *,
    steps: int,
    batch_size: int,
    learning_rate: float,
    lora_rank: int,
    device: str,
    tokenizer: str | Path | None = None,
    seed: int = 0,
    on_step: Callable[[int, float], None] | None = None,
    num_workers: int = 4,
    prompt_template: PromptTemplate,
) -> Path:
    """Train a rank-``lora_rank`` LoRA adapter for the PI05 checkpoint folder ``pretrained`` on the LeRobotDataset
    at ``dataset_root`` and write ``out``/checkpoint, ``out``/adapter and ``out``/train_log.csv; returns ``out``.

    ``tokenizer`` is a local tokenizer folder replacing the gated hub one the processors name; ``on_step``
    is called with (step, loss) after every optimiser step; every prompt of the dataset must fit ``prompt_template``
    (its task's, which the controller will check). ``num_workers`` data-loader processes (lerobot-train's
    default 4) read the samples: lerobot decodes every column of each action-chunk row, camera images included.
    """
    if steps < 1 or batch_size < 1 or lora_rank < 1 or num_workers < 0 or not learning_rate > 0:
        raise ValueError(f"steps, batch_size and lora_rank must be >= 1, num_workers >= 0 and learning_rate > 0; got "
                         f"steps={steps}, batch_size={batch_size}, lora_rank={lora_rank}, num_workers={num_workers}, "
                         f"learning_rate={learning_rate}")
    dataset_root = local_folder(dataset_root, "dataset", "meta/info.json")
    pretrained = local_folder(pretrained, "pretrained PI05", WEIGHTS_FILE)
    tokenizer = None if tokenizer is None else local_folder(tokenizer, "tokenizer")
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise FileExistsError(f"{out} already exists and is not empty; a finetuned PI05 is written to a new folder")

    from lerobot.configs import FeatureType
    from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot.utils.feature_utils import dataset_to_policy_features
    from peft import LoraConfig, get_peft_model

    repo_id = f"local/{dataset_root.name}"  # with root given, lerobot reads the local files only
    meta = LeRobotDatasetMetadata(repo_id, root=dataset_root)
    config = load_pi05_config(pretrained, "pretrained PI05")
    config.device = device
    features = dataset_to_policy_features(meta.features)  # images channel-first, as the policy takes them
    config.input_features = {key: f for key, f in features.items() if f.type is not FeatureType.ACTION}
    config.output_features = {key: f for key, f in features.items() if f.type is FeatureType.ACTION}
    check_features(config, IMAGE_KEYS, f"dataset {dataset_root} (to finetune PI05 {pretrained})")
    for task in meta.tasks.index:
        try:
            parse_prompt(task, prompt_template)
        except ValueError as err:
            raise ValueError(f"dataset {dataset_root} has a task outside the prompt contract, which the controller "
                             f"would refuse: {err}") from None
    if meta.stats is None:
        raise ValueError(f"dataset {dataset_root} has no meta/stats.json; finalize() it after recording")

    # Each sample: the frame's observation and its chunk of chunk_size actions (action_is_pad past the episode's end).
    delta_timestamps = resolve_delta_timestamps(config, meta)
    if delta_timestamps != {ACTION_KEY: [i / meta.fps for i in range(config.chunk_size)]}:
        raise RuntimeError(f"lerobot asks PI05 samples for {delta_timestamps}, not one chunk of {config.chunk_size} "
                           "actions")
    dataset = LeRobotDataset(repo_id, root=dataset_root, delta_timestamps=delta_timestamps,
                             video_backend="pyav")  # decodes videos, if any, without torchcodec's FFmpeg libraries
    if len(dataset) < batch_size:
        raise ValueError(f"dataset {dataset_root} has {len(dataset)} frames, fewer than batch_size={batch_size}")
    normalisation = {"features": {**config.input_features, **config.output_features},
                     "norm_map": config.normalization_mapping, "stats": meta.stats}
    preprocessor_overrides: dict[str, dict[str, Any]] = {
        "device_processor": {"device": device}, "normalizer_processor": normalisation,
        "rename_observations_processor": {"rename_map": {}},  # the dataset already uses the policy's names
    }
    if tokenizer is not None:
        preprocessor_overrides["tokenizer_processor"] = {"tokenizer_name": str(tokenizer)}
    preprocess, postprocess = make_pre_post_processors(
        config, pretrained_path=str(pretrained), preprocessor_overrides=preprocessor_overrides,
        postprocessor_overrides={"unnormalizer_processor": {**normalisation, "features": config.output_features}},
    )

    torch.manual_seed(seed)
    policy = load_checked_policy(pretrained, config, f"pretrained PI05 {pretrained}")
    model = get_peft_model(policy, LoraConfig(r=lora_rank, **policy._get_default_peft_targets()))
    trained = {name: p for name, p in model.named_parameters() if p.requires_grad}
    if not trained or any("lora_" not in name for name in trained):
        raise RuntimeError(f"LoRA should train only its own factors, but trains {sorted(trained)[:5]}")
    optimizer = torch.optim.AdamW(trained.values(), lr=learning_rate, betas=config.optimizer_betas,
                                  eps=config.optimizer_eps, weight_decay=config.optimizer_weight_decay)

    out.mkdir(parents=True, exist_ok=True)
    model.train()
    batches = _batches(dataset, batch_size, seed, num_workers)
    with open(out / LOG_FILE, "w", newline="") as f:
        log = csv.writer(f)
        log.writerow(["step", "loss"])
        for step in range(1, steps + 1):
            loss, _ = policy.forward(preprocess(next(batches)))
            if not math.isfinite(loss.item()):
                raise FloatingPointError(f"PI05 finetuning loss is {loss.item()} at step {step}")
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(trained.values(), config.optimizer_grad_clip_norm)
            optimizer.step()
            log.writerow([step, f"{loss.item():.6f}"])
            f.flush()
            if on_step is not None:
                on_step(step, loss.item())
    model.eval()

    checkpoint = out / CHECKPOINT_DIR
    checkpoint.mkdir()
    config.save_pretrained(checkpoint)  # the dataset's features
    shutil.copyfile(pretrained / WEIGHTS_FILE, checkpoint / WEIGHTS_FILE)  # the frozen base, unchanged
    preprocess.save_pretrained(checkpoint)
    postprocess.save_pretrained(checkpoint)
    model.save_pretrained(out / ADAPTER_DIR)
    return out


def _batches(dataset: Any, batch_size: int, seed: int, num_workers: int) -> Iterator[dict[str, Any]]:
    """Shuffled full batches, epoch after epoch, collated as lerobot's trainer does."""
    from lerobot.utils.collate import lerobot_collate_fn

    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, shuffle=True, drop_last=True,
                                         collate_fn=lerobot_collate_fn, num_workers=num_workers,
                                         persistent_workers=num_workers > 0,
                                         generator=torch.Generator().manual_seed(seed))
    while True:
        yield from loader


__all__ = ["finetune_pi05"]
