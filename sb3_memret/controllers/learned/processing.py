"""Observations and prompts to the learned policy's inputs, the same at training and at acting."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
from torch.nn import functional as F

from sb3_memret.controllers.base import Obs
from sb3_memret.controllers.learned.configuration import LearnedPolicyConfig
from sb3_memret.controllers.observation import camera_images, observation_state
from sb3_memret.memory.encoder import MiniLMEncoder


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


def image_tensor(images: np.ndarray | torch.Tensor, size: int) -> torch.Tensor:
    """(B, H, W, 3) uint8 or (B, 3, H, W) float in [0, 1] -> (B, 3, size, size) float in [0, 1]."""
    x = torch.as_tensor(images)
    if x.dtype == torch.uint8:
        x = x.permute(0, 3, 1, 2).float() / 255.0
    if x.ndim != 4 or x.shape[1] != 3:
        raise ValueError(f"camera images must be (B, H, W, 3) uint8 or (B, 3, H, W) float, got {tuple(x.shape)}")
    return F.interpolate(x, size=(size, size), mode="area")


class LearnedPolicyProcessor:
    """Builds the policy's inputs from a batched task observation and the prompts."""

    def __init__(self, config: LearnedPolicyConfig, tokenizer: PromptTokenizer | None = None):
        self.config = config
        self.tokenizer = tokenizer or PromptTokenizer()

    def __call__(self, obs: Obs, prompts: Sequence[str]) -> dict[str, torch.Tensor | list[torch.Tensor]]:
        state = torch.from_numpy(observation_state(obs))
        if state.shape[1] != self.config.state_dim:
            raise ValueError(f"the observation gives {state.shape[1]} state features, the policy takes "
                             f"{self.config.state_dim}")
        tokens, mask = self.tokenizer(prompts)
        images = []
        if self.config.image_features:
            frames = camera_images(obs)
            images = [image_tensor(frames[key], self.config.image_size) for key in self.config.image_features]
        return {"state": state, "tokens": tokens, "token_mask": mask, "images": images}
