"""What every expert on the harness's inputs alone keeps and reads, whatever its task.

A camera expert plays a detector-fed expert's plan on what MIKASA's harness gives a policy: the base camera's image,
the hand's pose (no joint velocities) and the gripper's opening. ``HarnessExpert`` is the part they share: it
declares those inputs in the spec (``needs_images``, ``harness_inputs``), dead-reckons the hand's motion
(``DeadReckonedHand``), reads one call's inputs, and clears the per-env perception the expert keeps with each
episode (its ``_forget`` and ``_forget_env``).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.tasks.mikasa.core.hand_motion import DeadReckonedHand


class HarnessInputs(NamedTuple):
    """One call's inputs: TCP poses (B, 7), the fingers' gaps (B,), the TCP's estimated steps (B, 3) and the base
    camera's images (B, H, W, 3)."""

    tcp: np.ndarray
    gaps: np.ndarray
    steps: np.ndarray
    rgb: Any


class HarnessExpert:
    """A mixin, first among a camera expert's bases (``class CameraX(HarnessExpert, XController)``); the expert calls
    ``_on_harness`` in its ``__init__`` and says what it forgets at an episode's start."""

    def _on_harness(self, paced_every: int, chunk_len: int) -> None:
        """Declare the harness's inputs; ``paced_every``: the control steps executed between calls."""
        self.spec = dataclasses.replace(self.spec, needs_images=True, harness_inputs=True)
        self.stateful = True  # its perception (never what its prompt says)
        self.paced_every = paced_every
        self.hand = DeadReckonedHand(paced_every, chunk_len)

    def reset(self, seeds: Sequence[int]) -> None:
        super().reset(seeds)
        self.hand.reset(len(seeds))
        self._forget(len(seeds))

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        super().reset_envs(env_ids, seeds)
        for i in env_ids:
            self.hand.reset_env(i)
            self._forget_env(i)

    def _forget(self, n_envs: int) -> None:
        """Start every env's perception afresh (``n_envs`` of them)."""
        raise NotImplementedError

    def _forget_env(self, i: int) -> None:
        """Start env ``i``'s perception afresh."""
        raise NotImplementedError

    def _harness_inputs(self, obs: Obs, n_prompts: int) -> HarnessInputs:
        if n_prompts != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {n_prompts} prompts")
        tcp = as_numpy(obs["extra"]["tcp_pose"]).astype(np.float64)
        gaps = as_numpy(obs["agent"]["qpos"]).astype(np.float64)[:, 7:9].sum(axis=1)
        return HarnessInputs(tcp, gaps, self.hand.steps(tcp[:, :3]), obs["sensor_data"]["base_camera"]["rgb"])

    def _ran(self, inputs: HarnessInputs, chunks: np.ndarray) -> np.ndarray:
        """Record the chunks sent (the hand's motion is reckoned from them) and return them."""
        self.hand.ran(inputs.tcp[:, :3], inputs.steps, chunks)
        return chunks


__all__ = ["HarnessExpert", "HarnessInputs"]
