"""The learned, language-conditioned controller as a frozen controller the memory serves."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from sb3_memret.controllers.base import ControllerSpec, FrozenController, Obs
from sb3_memret.controllers.learned.modeling import LearnedPolicy
from sb3_memret.controllers.learned.processing import InputLayout, LearnedPolicyProcessor, PromptTokenizer
from sb3_memret.controllers.shipped import default_checkpoint
from sb3_memret.controllers.prompts import ParsedPrompt


class LearnedController(FrozenController):
    """A LearnedPolicy checkpoint acting on the task's state (and cameras, if it was trained on them).

    It keeps no state between calls, so ``reset`` only records how many envs a batch holds.
    """

    stateful = False

    def __init__(self, checkpoint: str | Path | None, task: InputLayout, device: str = "cpu",
                 tokenizer: PromptTokenizer | None = None):
        self.checkpoint = Path(checkpoint) if checkpoint is not None else default_checkpoint()
        self.device = torch.device(device)
        self.policy = LearnedPolicy.from_pretrained(self.checkpoint, self.device)
        config = self.policy.config
        self.processor = LearnedPolicyProcessor(config, task, tokenizer, self.device)
        self.spec = ControllerSpec(
            action_convention=config.action_convention,
            chunk_len=config.chunk_len,
            action_dim=config.action_dim,
            needs_images=bool(config.image_features),
            prompt_template=config.prompt_template(task.prompt_template.fields),
            robot=config.robot,
            harness_inputs=bool(config.image_features) and self.processor.harness_only,
        )
        self._num_envs = 0

    def reset(self, seeds: Sequence[int]) -> None:
        self._num_envs = len(seeds)

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        self._check_env_ids(env_ids, seeds, self._num_envs)

    @torch.no_grad()
    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if self._num_envs != len(prompts):
            raise RuntimeError(f"reset() was called for {self._num_envs} envs but act() got {len(prompts)} prompts")
        for prompt in parsed:
            self.processor.task.check_prompt(prompt)  # a value the task has no place for: refused, not guessed at
        inputs = self.processor(obs, prompts)
        prompt = self.policy.encode_prompts(inputs["tokens"], inputs["token_mask"])
        features = self.policy.camera_features(inputs["images"])
        chunks = self.policy(inputs["state"], prompt, features)
        return chunks.cpu().numpy()
