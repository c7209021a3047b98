"""Observations and prompts to the learned policy's inputs, the same at training and at acting.

The state comes from the task's demonstration layout (``Task.controller_inputs``), picked by name
(``LearnedPolicyConfig.state_names``; MIKASA's harness proprioception, ``harness_proprio``, is derived from the
layout's hand pose and fingers as at training); camera images are area-resized to the policy's size with the
same uint8 rounding the demonstrations were stored with.
"""

from __future__ import annotations

from typing import Any, Protocol, Sequence

import numpy as np
import torch

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.harness_proprio import (HARNESS_PROPRIO_NAMES, harness_proprio, reads_harness_proprio,
                                                    with_harness_proprio)
from sb3_memret.controllers.learned.configuration import LearnedPolicyConfig
from sb3_memret.controllers.observation import IMAGE_KEYS, STATE_KEY, resize_image_tensor
from sb3_memret.memory.encoder import MiniLMEncoder
from sb3_memret.controllers.prompts import ParsedPrompt


class InputLayout(Protocol):
    """What a learned controller reads of its task (a ``Task`` has it): its name, the names of its state
    features, and the controller's inputs per env of a batched observation."""

    name: str
    prompt_template: Any  # the task's PromptTemplate: its number fields are the controller's

    def state_names(self) -> Sequence[str]: ...

    def controller_inputs(self, obs: Any, n_envs: int, with_images: bool) -> dict[str, np.ndarray]: ...

    def check_prompt(self, prompt: ParsedPrompt) -> None: ...


class PromptTokenizer:
    """Prompts to padded MiniLM per-token features (B, T, 384) and their mask (B, T); cached by text."""

    def __init__(self, encoder: MiniLMEncoder | None = None):
        self.encoder = encoder or MiniLMEncoder()

    def __call__(self, prompts: Sequence[str]) -> tuple[torch.Tensor, torch.Tensor]:
        features = self.encoder.encode_tokens(prompts)
        length = max(len(f) for f in features)
        tokens = np.zeros((len(features), length, features[0].shape[1]), dtype=np.float32)
        mask = np.zeros((len(features), length), dtype=bool)
        for i, f in enumerate(features):
            tokens[i, : len(f)], mask[i, : len(f)] = f, True
        return torch.from_numpy(tokens), torch.from_numpy(mask)


def state_columns(available: Sequence[str], wanted: Sequence[str], where: str) -> np.ndarray:
    """Indices of ``wanted`` names in ``available``, or a ValueError naming the missing ones."""
    missing = [name for name in wanted if name not in available]
    if missing:
        raise ValueError(f"{where} has no state entries {missing}; it has {list(available)}")
    return np.array([list(available).index(name) for name in wanted], dtype=np.int64)


class LearnedPolicyProcessor:
    """Builds the policy's inputs, on ``device``: at acting from a batched observation of ``task`` and the prompts
    (``__call__``), at training from demonstration frames (``state``, ``camera``, ``tokenizer``): the same state
    picking, image scaling and prompt features on both sides, so what a policy learned from is what it acts on."""

    def __init__(self, config: LearnedPolicyConfig, task: InputLayout | None = None,
                 tokenizer: PromptTokenizer | None = None, device: str | torch.device = "cpu"):
        if task is not None and task.name not in config.served_tasks:
            served = " or ".join(repr(name) for name in config.served_tasks)
            raise ValueError(f"the learned controller was trained on task {served}, not {task.name!r}")
        self.config, self.task = config, task
        self.tokenizer = tokenizer or PromptTokenizer()
        self.device = torch.device(device)
        self.derives_harness = reads_harness_proprio(config.state_names)
        # a policy on the harness's inputs alone reads no other entry of the task's layout (``harness_inputs``)
        self.harness_only = self.derives_harness and set(config.state_names) <= set(HARNESS_PROPRIO_NAMES)
        if task is None:
            self.columns = None
        elif self.harness_only:
            self.columns = self.state_columns(HARNESS_PROPRIO_NAMES, "the harness's proprioception")
        else:
            self.columns = self.state_columns(self.layout(task.state_names()), f"task {task.name!r}'s observation layout")

    def layout(self, names: Sequence[str]) -> tuple[str, ...]:
        """The state entries the policy can pick from in a layout of ``names``: with the harness's seven appended
        where it reads them."""
        return (*names, *HARNESS_PROPRIO_NAMES) if self.derives_harness else tuple(names)

    def state_columns(self, names: Sequence[str], where: str) -> np.ndarray:
        """Where the entries the policy reads (``config.state_names``) lie in a state laid out as ``names``."""
        return state_columns(names, self.config.state_names, where)

    def state(self, states: np.ndarray, columns: np.ndarray) -> torch.Tensor:
        """(N, S) states of some layout -> (N, state_dim) float32 of the entries the policy reads (``columns``)."""
        return torch.from_numpy(np.ascontiguousarray(states[:, columns]).astype(np.float32, copy=False)).to(self.device)

    def camera(self, images: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) uint8 images -> (B, 3, image_size, image_size) float in [0, 1], resized as the
        demonstrations were stored."""
        return resize_image_tensor(images.to(self.device), self.config.image_size) / 255.0

    def __call__(self, obs: Obs, prompts: Sequence[str]) -> dict[str, torch.Tensor | list[torch.Tensor]]:
        if self.task is None:
            raise ValueError("a processor without a task builds training inputs only; give it the task to act on")
        inputs = harness_inputs(obs, self.config.image_features) if self.harness_only else \
            self.task.controller_inputs(obs, len(prompts), bool(self.config.image_features))
        states = inputs[STATE_KEY]
        if self.derives_harness and not self.harness_only:
            states, _ = with_harness_proprio(states, self.task.state_names())
        state = self.state(states, self.columns)
        tokens, mask = self.tokenizer(prompts)
        images = [self.camera(channels_first(inputs[key])) for key in self.config.image_features]
        return {"state": state, "tokens": tokens.to(self.device), "token_mask": mask.to(self.device), "images": images}


def harness_inputs(obs: Obs, image_features: Sequence[str]) -> dict[str, np.ndarray]:
    """A policy's inputs from what MIKASA's harness gives alone, batched: the seven proprioception numbers (from the
    observation's hand pose and finger joints, as ``harness_proprio`` derives them at training) and the cameras."""
    qpos = as_numpy(obs["agent"]["qpos"])
    inputs = {STATE_KEY: harness_proprio(as_numpy(obs["extra"]["tcp_pose"]).reshape(len(qpos), -1),
                                         qpos.reshape(len(qpos), -1)[:, 7:9])}
    for feature in image_features:
        inputs[feature] = as_numpy(obs["sensor_data"][IMAGE_KEYS[feature]]["rgb"])
    return inputs


def channels_first(images: np.ndarray) -> torch.Tensor:
    """(B, H, W, 3) uint8 camera images -> a (B, 3, H, W) uint8 tensor (the uint8 frames travel, a quarter of the
    float bytes), or a ValueError naming what came instead."""
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ValueError(f"camera images must be (B, H, W, 3) uint8, got {images.dtype}{images.shape}")
    return torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2)
