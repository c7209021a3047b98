"""The learned, language-conditioned controller as a frozen controller the memory serves."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from sb3_memret.controllers.base import ControllerSpec, FrozenController, Obs
from sb3_memret.controllers.learned.modeling import LearnedPolicy
from sb3_memret.controllers.learned.processing import LearnedPolicyProcessor, PromptTokenizer
from sb3_memret.prompts import ParsedPrompt

CHECKPOINTS = Path(__file__).resolve().parent.parent / "checkpoints"
# shipped checkpoints by controller name, and the make target that rebuilds each
SHIPPED: dict[str, tuple[Path, str]] = {
    "learned": (CHECKPOINTS / "drawer-learned", "controller"),  # the seed's task: the cube alone
    "learned-objects": (CHECKPOINTS / "drawer-objects-learned", "controller-objects"),  # any object the instruction names
}


def default_checkpoint(name: str = "learned") -> Path:
    """The checkpoint ``--controller NAME`` names: trained by ``make controller`` (or ``controller-objects``) and
    shipped in the package."""
    if name not in SHIPPED:
        raise ValueError(f"no shipped learned controller {name!r}; shipped are {sorted(SHIPPED)}")
    folder, target = SHIPPED[name]
    if not (folder / "model.safetensors").is_file():
        raise FileNotFoundError(f"the shipped learned controller {name!r} is missing from {folder}; rebuild it "
                                f"with `make {target}` (demos, then finetune)")
    return folder


class LearnedController(FrozenController):
    """A LearnedPolicy checkpoint acting on the task's state (and cameras, if it was trained on them).

    It keeps no state between calls, so ``reset`` only records how many envs a batch holds.
    """

    stateful = False

    def __init__(self, checkpoint: str | Path | None = None, device: str = "cpu",
                 tokenizer: PromptTokenizer | None = None):
        self.checkpoint = Path(checkpoint) if checkpoint is not None else default_checkpoint()
        self.device = torch.device(device)
        self.policy = LearnedPolicy.from_pretrained(self.checkpoint, self.device)
        config = self.policy.config
        self.processor = LearnedPolicyProcessor(config, tokenizer)
        self.spec = ControllerSpec(
            action_convention=config.action_convention,
            chunk_len=config.chunk_len,
            action_dim=config.action_dim,
            needs_images=bool(config.image_features),
            prompt_template=config.prompt_template,
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
        inputs = self.processor(obs, prompts)
        prompt = self.policy.encode_prompts(inputs["tokens"].to(self.device), inputs["token_mask"].to(self.device))
        chunks = self.policy(inputs["state"].to(self.device), prompt,
                             [image.to(self.device) for image in inputs["images"]])
        return chunks.cpu().numpy()
