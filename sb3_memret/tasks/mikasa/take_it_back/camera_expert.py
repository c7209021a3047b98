"""TakeItBack's carry-back expert on what MIKASA's harness gives a policy alone: a protocol entry, not an upper bound.

``CarryBackController`` reads the cube's and the targets' positions from a simulated detector and the arm's joint
velocities, so its rows are a privileged upper bound. ``CameraCarryBackController`` is the same plan and motion on
the harness's inputs only (``ControllerSpec.harness_inputs``), each read from the base camera with its shipped
calibration:

- **the cube**: its top face's pixels in the first frame (``read_cube_top``, the bright green; 0.13-0.42 cm from
  the simulator's at development seeds 5000-5009), then carried by the hand (``HeldCube``: gripped when the fingers'
  gap closes on it within reach of where it was seen);
- **the red target**: its rings' red pixels in the first frame (``read_red_target``, cast onto the table; within
  1 cm of its centre, well inside MIKASA's 8 cm);
- **the phase**: the target turned purple (``purple_target_seen``), once, for the rest of the episode: from then on
  it carries the cube back to the start its prompt names;
- **the hand's motion**: dead-reckoned from the hand's pose and the actions that ran (``DeadReckonedHand``).

The start comes from its prompt alone, as for the detector's version. It keeps per-env perception (the cube, the
target, whether it turned, the hand's motion; ``reset``/``reset_envs`` clear it), never the start.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.carry_expert import GRIP_CLOSED, CarryBackController, CarryGains
from sb3_memret.tasks.mikasa.core.hand_motion import DeadReckonedHand
from sb3_memret.tasks.mikasa.core.held_object import HeldCube
from sb3_memret.tasks.mikasa.core.layout_perception import cast_mask, rgb_frame
from sb3_memret.tasks.mikasa.core.perception import REFERENCE_SIZE
from sb3_memret.tasks.mikasa.core.touch_expert import TouchGains

CUBE_TOP_Z, CUBE_CENTRE_Z = 0.04, 0.02  # the 4 cm cube's top face and centre, standing on the table
TARGET_Z = 0.001  # the targets' height
MIN_PIXELS = {"cube": 6, "target": 40, "purple": 40}  # at 128x128: the cube's top shows 11-16, a target about 200


def read_cube_top(rgb: Any) -> np.ndarray | None:
    """The cube's table (x, y) from one base-camera frame: its top face (bright green, about (4, 231, 4)), cast onto
    that face's plane; None when not in sight."""
    frame = rgb_frame(rgb)
    return cast_mask((frame[..., 1] >= 200) & (frame[..., 0] <= 60) & (frame[..., 2] <= 60), CUBE_TOP_Z,
                     MIN_PIXELS["cube"])


def read_red_target(rgb: Any) -> np.ndarray | None:
    """The red target's table (x, y) from one base-camera frame: its rings' red (about (204, 71, 76); the wood's
    green channel is above 100), cast onto the table; None when not in sight."""
    frame = rgb_frame(rgb)
    return cast_mask((frame[..., 0] >= 150) & (frame[..., 1] <= 80) & (frame[..., 2] <= 80), TARGET_Z,
                 MIN_PIXELS["target"])


def purple_target_seen(rgb: Any) -> bool:
    """Whether one base-camera frame shows the purple target (about (180, 3, 212)) that replaces the red one."""
    frame = rgb_frame(rgb)
    mask = (frame[..., 0] >= 120) & (frame[..., 2] >= 150) & (frame[..., 1] <= 60)
    return bool(mask.sum() >= MIN_PIXELS["purple"] * np.prod(np.array(mask.shape) / REFERENCE_SIZE))


class CameraCarryBackController(CarryBackController):
    """Carries the cube to the red target, then, once the target turned purple, to the start its prompt names,
    reading only the base camera's image, the hand's pose and the gripper's opening (the module docstring says
    how). ``paced_every``: the control steps executed between its calls."""

    def __init__(self, starts: dict[str, tuple[float, float]], default: str, prompt_template: PromptTemplate,
                 paced_every: int, field: str = "side", chunk_len: int = 8, gains: TouchGains | None = None,
                 carry: CarryGains | None = None, read_cube: Callable[[Any], np.ndarray | None] = read_cube_top,
                 read_target: Callable[[Any], np.ndarray | None] = read_red_target,
                 turned: Callable[[Any], bool] = purple_target_seen):
        super().__init__(starts, default, prompt_template, field, chunk_len, gains, carry)
        self.hand = DeadReckonedHand(paced_every, chunk_len)
        self.spec = dataclasses.replace(self.spec, needs_images=True, harness_inputs=True)
        self.stateful = True  # its perception: the cube, the target, its turn, the hand's motion (never the start)
        self.paced_every = paced_every
        self.read_cube, self.read_target, self.turned = read_cube, read_target, turned
        self.cube = HeldCube(self.carry)
        self.targets: list[np.ndarray | None] = []
        self.returning: list[bool] = []

    def reset(self, seeds: Sequence[int]) -> None:
        super().reset(seeds)
        self.cube.reset(len(seeds))
        self.targets, self.returning = [None] * len(seeds), [False] * len(seeds)
        self.hand.reset(len(seeds))

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        super().reset_envs(env_ids, seeds)
        for i in env_ids:
            self.cube.reset_env(i)
            self.targets[i], self.returning[i] = None, False
            self.hand.reset_env(i)

    def reads_images(self) -> bool:
        """Until every env's target has turned: the cube is carried from where it was seen."""
        return not self.returning or not all(self.returning)

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        tcp = as_numpy(obs["extra"]["tcp_pose"]).astype(np.float64)
        gaps = as_numpy(obs["agent"]["qpos"]).astype(np.float64)[:, 7:9].sum(axis=1)
        steps = self.hand.steps(tcp[:, :3])
        rgb = obs["sensor_data"]["base_camera"]["rgb"]
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            if self.cube.places[i] is None:
                seen = self.read_cube(rgb[i])
                self.cube.see(i, None if seen is None else np.array([*seen, CUBE_CENTRE_Z]))
            if self.targets[i] is None:
                self.targets[i] = self.read_target(rgb[i])
            if not self.returning[i]:
                self.returning[i] = bool(self.turned(rgb[i]))
            if self.cube.places[i] is None or (self.targets[i] is None and not self.returning[i]):
                continue  # the cube or the target not yet in sight: hold still
            cube = self.cube.track(i, tcp[i, :3], float(gaps[i]))
            destination = self.start_of(p) if self.returning[i] else self.targets[i]
            goal = self._goal(tcp[i, :3], cube, float(gaps[i]), destination, returning=self.returning[i])
            if goal is None:
                chunks[i, :, -1] = GRIP_CLOSED  # there: hold the cube still
            else:
                chunks[i] = self._chunk(tcp[i], steps[i], goal)
        self.hand.ran(tcp[:, :3], steps, chunks)
        return chunks


__all__ = ["CameraCarryBackController", "purple_target_seen", "read_cube_top", "read_red_target"]
