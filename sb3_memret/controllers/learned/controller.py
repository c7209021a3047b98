"""The learned, language-conditioned controller as a frozen controller the memory serves."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
import torch

from sb3_memret.controllers.base import ControllerSpec, FrozenController, Obs
from sb3_memret.controllers.learned.modeling import LearnedPolicy
from sb3_memret.controllers.learned.processing import LearnedPolicyProcessor, PromptTokenizer
from sb3_memret.prompts import ParsedPrompt

if TYPE_CHECKING:
    from sb3_memret.tasks import Task

CHECKPOINTS = Path(__file__).resolve().parent.parent / "checkpoints"
# shipped checkpoints by (task, controller name): the folder, and the make command that rebuilds it. ``learned`` is
# the camera-reading controller (cameras and what the robot reads of itself); ``learned-state`` the drawer's policy on
# the simulator's state, whose cube detection is perfect perception.
SHIPPED: dict[tuple[str, str], tuple[Path, str]] = {
    ("drawer", "learned"): (CHECKPOINTS / "drawer-camera", "make controller-camera"),
    ("drawer", "learned-state"): (CHECKPOINTS / "drawer-learned", "make controller"),
    ("drawer", "learned-objects"): (CHECKPOINTS / "drawer-objects-learned", "make controller-objects"),  # state
    ("RememberColor3-VLA-v0", "learned"): (CHECKPOINTS / "RememberColor3-VLA-v0-camera",
                                           "make controller-mikasa MIKASA_TASK=RememberColor3-VLA-v0"),
}


def shipped_names(task: str = "drawer") -> list[str]:
    """The shipped learned controllers of ``task``, by ``--controller`` name."""
    return sorted(name for t, name in SHIPPED if t == task)


def default_checkpoint(name: str = "learned", task: str = "drawer") -> Path:
    """The checkpoint ``--controller NAME`` names on ``task``: trained by its make target and shipped in the
    package."""
    if (task, name) not in SHIPPED:
        raise ValueError(f"no shipped learned controller {name!r} for task {task!r}; shipped are "
                         f"{shipped_names(task) or 'none'} (or train one: sb3-memret demos, then finetune)")
    folder, command = SHIPPED[task, name]
    if not (folder / "model.safetensors").is_file():
        raise FileNotFoundError(f"the shipped learned controller {name!r} of task {task!r} is missing from {folder}; "
                                f"rebuild it with `{command}` (demos, then finetune)")
    return folder


class LearnedController(FrozenController):
    """A LearnedPolicy checkpoint acting on the task's state (and cameras, if it was trained on them).

    It keeps no state between calls, so ``reset`` only records how many envs a batch holds.
    """

    stateful = False

    def __init__(self, checkpoint: str | Path | None = None, device: str = "cpu",
                 tokenizer: PromptTokenizer | None = None, task: "str | Task | None" = None):
        from sb3_memret.tasks import make_task

        self.checkpoint = Path(checkpoint) if checkpoint is not None else default_checkpoint()
        self.device = torch.device(device)
        self.policy = LearnedPolicy.from_pretrained(self.checkpoint, self.device)
        config = self.policy.config
        self.processor = LearnedPolicyProcessor(config, make_task(task if task is not None else config.task), tokenizer)
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
        features = self.policy.camera_features([image.to(self.device) for image in inputs["images"]])
        chunks = self.policy(inputs["state"].to(self.device), prompt, features)
        return chunks.cpu().numpy()
