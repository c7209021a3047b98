"""The one interface every frozen low-level policy implements."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate, parse_prompt

Obs = Mapping[str, Any]

# SAPIEN renders with Vulkan. On a CPU-only machine that takes a software driver newer than Debian 12's
# lavapipe (Mesa 22.3 lacks VK_KHR_external_semaphore_fd); `make renderer` unpacks Mesa 25's.
RENDER_HINT = (
    "create the env with obs_mode='rgb' and a render backend: render_backend='gpu' on a machine with a "
    "Vulkan GPU driver, or render_backend='cpu' on a CPU-only machine, which renders with the software "
    "Vulkan driver lavapipe (Mesa >= 24.3) that `make renderer` installs into .renderer/"
)


@dataclass(frozen=True)
class ControllerSpec:
    """What a frozen controller was trained with, checked before it is allowed to act.

    ``action_convention`` names the env control mode its actions are meant for (actions are
    sent unmodified, so it must match); ``chunk_len`` is the horizon of one ``act`` call;
    ``needs_images`` says it reads camera images; ``prompt_template`` lists its training
    prompts' wording; ``robot`` is the robot a camera controller saw in training (it learns its
    look: the drawer's camera policy lost half its successes to a Panda drawn with coarser meshes);
    ``harness_inputs`` that it reads nothing but what MIKASA's harness gives a policy (both cameras, the 7-D
    proprioception of ``harness_proprio``, the prompt): the benchmark then hands it that alone, and its rows are a
    protocol entry rather than a privileged upper bound.
    """

    action_convention: str
    chunk_len: int
    prompt_template: PromptTemplate
    action_dim: int = 7
    needs_images: bool = False
    robot: str | None = None  # a camera controller: the robot its training images showed (None: any)
    harness_inputs: bool = False


class FrozenController(ABC):
    """A frozen policy: prompts and observations in, action chunks out, never trained here.

    ``act`` is batched: one call serves every env of a batch. Observations follow the
    DrawerCubeTakeOut-v1 ``state_dict``/``rgb`` layout with a leading batch dimension.
    """

    spec: ControllerSpec
    stateful: bool = True  # keeps per-episode state between act calls (False: only the observation matters)

    @abstractmethod
    def reset(self, seeds: Sequence[int]) -> None:
        """Start a new episode in each of ``len(seeds)`` envs: the batch ``act`` serves from now on."""

    @abstractmethod
    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        """Start new episodes in envs ``env_ids`` of the current batch only (one env's episode ends while
        the others' go on); ``seeds[j]`` is env ``env_ids[j]``'s."""

    def _check_env_ids(self, env_ids: Sequence[int], seeds: Sequence[int], batch: int) -> None:
        if len(env_ids) != len(seeds):
            raise ValueError(f"reset_envs got {len(env_ids)} env ids but {len(seeds)} seeds")
        bad = [i for i in env_ids if not 0 <= i < batch]
        if bad:
            raise ValueError(f"env ids {bad} are outside the batch of {batch} that reset() set up")

    @abstractmethod
    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        """Return action chunks (B, chunk_len, action_dim) for checked prompts (raw and parsed)."""

    def act(self, obs: Obs, prompts: Sequence[str], check_prompts: bool = True) -> np.ndarray:
        """Check every prompt against the training template, then predict (B, H, action_dim).

        ``check_prompts=False`` waives the prompt contract: only for measuring how a controller
        copes with wording it was never trained on (``ablate wording``). A prompt that does not
        parse then reaches ``_act`` as its first sentence with no facts.
        """
        if check_prompts:
            parsed = [parse_prompt(prompt, self.spec.prompt_template) for prompt in prompts]
        else:
            parsed = [_parse_or_bare(prompt, self.spec.prompt_template) for prompt in prompts]
        chunks = np.asarray(self._act(obs, prompts, parsed), dtype=np.float32)
        expected = (len(prompts), self.spec.chunk_len, self.spec.action_dim)
        if chunks.shape != expected:
            raise RuntimeError(f"{type(self).__name__} returned chunks of shape {chunks.shape}, expected {expected}")
        return chunks

    def reads_images(self) -> bool:
        """Whether its next call reads the cameras' images: ``spec.needs_images``, unless its perception is complete
        for the episodes under way (an expert that placed every object once); a runner may then skip rendering."""
        return self.spec.needs_images

    def check_env(self, env: Any) -> None:
        """Refuse an env whose action convention or observations do not match this controller."""
        base = getattr(env, "unwrapped", env)
        mode = getattr(base, "control_mode", None)
        if mode != self.spec.action_convention:
            raise ValueError(
                f"{type(self).__name__} emits {self.spec.action_convention!r} actions but the env's control "
                f"mode is {mode!r}; create the env with control_mode={self.spec.action_convention!r}"
            )
        if self.spec.needs_images and "rgb" not in str(getattr(base, "obs_mode", "")):
            raise ValueError(
                f"{type(self).__name__} needs camera images but the env's obs_mode is {base.obs_mode!r}; "
                + RENDER_HINT
            )
        robot = env_robot(base)
        if self.spec.needs_images and self.spec.robot is not None and robot is not None and robot != self.spec.robot:
            raise ValueError(
                f"{type(self).__name__} was trained on camera images of robot {self.spec.robot!r} but the env "
                f"renders {robot!r}; create the env with robot_uids={self.spec.robot!r}, or train the controller on "
                f"demonstrations of {robot!r}"
            )


def env_robot(env: Any) -> str | None:
    """The ManiSkill robot uid an env (or the ``TaskEnvInfo`` of one) simulates; None where it does not say."""
    agent = getattr(env, "agent", None)
    if agent is not None:
        return getattr(agent, "uid", None)
    robot = getattr(env, "robot", None)
    return robot if isinstance(robot, str) else None


def _parse_or_bare(prompt: str, template: PromptTemplate) -> ParsedPrompt:
    """The parsed prompt, or its first sentence with no facts when it is worded off the template."""
    try:
        return parse_prompt(prompt, template)
    except ValueError:
        return ParsedPrompt(prompt.split(".")[0] + ".")


def as_numpy(x: Any) -> np.ndarray:
    """A numpy view of a torch tensor (any device) or array-like observation entry."""
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)
