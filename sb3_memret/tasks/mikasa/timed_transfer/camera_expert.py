"""TimedTransfer's timed carry expert on what MIKASA's harness gives a policy alone: a protocol entry, not an upper
bound.

``TimedTransferController`` reads the cube's and the discs' positions from a simulated detector and the arm's joint
velocities, so its rows are a privileged upper bound. ``CameraTimedTransferController`` is the same plan and motion
on the harness's inputs only (``ControllerSpec.harness_inputs``):

- **the cube**: its blue pixels in the base camera's first frame (``read_blue_cube``: its top face, about a dozen
  pixels at 128x128), cast with the camera's shipped calibration onto the plane of that face;
- **the red disc**: where MIKASA lays it, ``DISC_SEPARATION`` (22 cm) along +y from the green disc, whose centre the
  cube rests on at the reset;
- **the cube in hand**: the fingers' gap (the harness's gripper opening) closed on it within reach of where it was
  seen; from then on it is carried at the offset from the hand it was gripped at, and let go it stays where it was
  last carried to (``HeldCube``);
- **the hand's motion**: dead-reckoned from the hand's pose and the actions that ran (``DeadReckonedHand``, at the
  pace it declares, ``paced_every``).

The count comes from its prompt alone, as for the detector's version. It keeps per-env perception (the cube's place
and grip, the hand's last position and step; ``reset``/``reset_envs`` clear it), never the count.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import numpy as np
from scipy import ndimage

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.carry_expert import CarryGains
from sb3_memret.tasks.mikasa.core.hand_motion import DeadReckonedHand
from sb3_memret.tasks.mikasa.core.held_object import HeldCube
from sb3_memret.tasks.mikasa.core.layout_perception import table_points
from sb3_memret.tasks.mikasa.core.perception import REFERENCE_SIZE
from sb3_memret.tasks.mikasa.core.touch_expert import TouchGains
from sb3_memret.tasks.mikasa.timed_transfer.expert import TimedGains, TimedTransferController

RED_DISC_OFFSET = np.array([0.0, 0.22, 0.0])  # MIKASA's DISC_SEPARATION: the red disc from the green one
DISC_CENTRE_Z = 0.003  # the discs' centre height
CUBE_CENTRE_Z = 0.026  # the cube's centre resting on the green disc
CUBE_TOP_Z = 0.046  # ... and its top face, the part of it the base camera shows blue
MIN_CUBE_PIXELS = 4  # at 128x128: the cube shows about a dozen


def read_blue_cube(rgb: np.ndarray, intrinsic: np.ndarray, extrinsic: np.ndarray) -> np.ndarray | None:
    """The blue cube's table (x, y) from one base-camera frame (H, W, 3): its pixels' largest blob (blue well above
    red and green: its top face renders about (87, 87, 216), nothing else in the scene is blue), cast along the
    camera ray onto the plane of that face; None when not in sight. 0.05-0.62 cm from the simulator's at development
    seeds 5000-5009 of TimedTransferEasy."""
    rgb = np.asarray(rgb).astype(np.int16)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"expected one (H, W, 3) frame, got shape {rgb.shape}")
    mask = (rgb[..., 2] >= 150) & (rgb[..., 2] - np.maximum(rgb[..., 0], rgb[..., 1]) >= 80)
    labels, n_blobs = ndimage.label(mask, structure=np.ones((3, 3)))
    if n_blobs == 0:
        return None
    sizes = np.bincount(labels.ravel(), minlength=n_blobs + 1)[1:]
    if sizes.max() < MIN_CUBE_PIXELS * np.prod(np.array(rgb.shape[:2]) / REFERENCE_SIZE):
        return None
    pixels = np.argwhere(labels == int(sizes.argmax()) + 1).mean(axis=0) + 0.5
    point = table_points(pixels[None], intrinsic, extrinsic, CUBE_TOP_Z)[0]
    return point if np.isfinite(point).all() else None


def base_camera_blue_cube(rgb: Any) -> np.ndarray | None:
    """``read_blue_cube`` of one base-camera frame with the camera's shipped calibration."""
    return read_blue_cube(np.asarray(as_numpy(rgb)), BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC)


class CameraTimedTransferController(TimedTransferController):
    """Carries the blue cube over the red disc and sets it down on the step its instruction names, reading only the
    base camera's image, the hand's pose and the gripper's opening (the module docstring says how). ``paced_every``:
    the control steps executed between its calls; ``read_cube``: image -> the cube's table (x, y), or None (the base
    camera's reader by default)."""

    def __init__(self, prompt_template: PromptTemplate, paced_every: int, chunk_len: int = 8,
                 gains: TouchGains | None = None, carry: CarryGains | None = None, timing: TimedGains | None = None,
                 read_cube: Callable[[Any], np.ndarray | None] | None = None):
        super().__init__(prompt_template, chunk_len, gains, carry, timing)
        self.hand = DeadReckonedHand(paced_every, chunk_len)
        self.spec = dataclasses.replace(self.spec, needs_images=True, harness_inputs=True)
        self.stateful = True  # its perception: the cube's place and grip, the hand's motion (never the count)
        self.paced_every, self.read_cube = paced_every, read_cube or base_camera_blue_cube
        self.starts: list[np.ndarray | None] = []  # each env's cube at the reset: the green disc's centre
        self.cube = HeldCube(self.carry)  # ... and where it is now, as far as it knows

    def reset(self, seeds: Sequence[int]) -> None:
        super().reset(seeds)
        self.starts = [None] * len(seeds)
        self.cube.reset(len(seeds))
        self.hand.reset(len(seeds))

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        super().reset_envs(env_ids, seeds)
        for i in env_ids:
            self.starts[i] = None
            self.cube.reset_env(i)
            self.hand.reset_env(i)

    def reads_images(self) -> bool:
        """Until every env has seen its cube: then the hand carries what it knows."""
        return not self.starts or any(start is None for start in self.starts)

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        tcp = as_numpy(obs["extra"]["tcp_pose"]).astype(np.float64)
        gaps = as_numpy(obs["agent"]["qpos"]).astype(np.float64)[:, 7:9].sum(axis=1)
        steps = self.hand.steps(tcp[:, :3])
        rgb = obs["sensor_data"]["base_camera"]["rgb"]
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            if self.starts[i] is None:
                seen = self.read_cube(rgb[i])
                if seen is None:
                    continue  # the cube not yet in sight: hold still
                self.starts[i] = np.array([*seen, CUBE_CENTRE_Z])
                self.cube.see(i, self.starts[i])
            cube = self.cube.track(i, tcp[i, :3], float(gaps[i]))
            red = self.starts[i] + RED_DISC_OFFSET
            red[2] = DISC_CENTRE_Z
            goal = self._goal(tcp[i, :3], cube, float(gaps[i]), red, self.due(p))
            chunks[i] = self._chunk(tcp[i], steps[i], goal)
        self.hand.ran(tcp[:, :3], steps, chunks)
        return chunks


__all__ = ["CUBE_CENTRE_Z", "CameraTimedTransferController", "RED_DISC_OFFSET", "base_camera_blue_cube",
           "read_blue_cube"]
