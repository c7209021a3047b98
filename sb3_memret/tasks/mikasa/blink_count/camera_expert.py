"""BlinkCountButtonPress's press expert on what MIKASA's harness gives a policy alone: a protocol entry, not an upper
bound.

``ButtonPressController`` reads the buttons' places and the phase lamp from a simulated detector and the arm's
joint velocities, so its rows are a privileged upper bound. ``CameraButtonPressController`` is the same stateless
plan and motion on the harness's inputs only (``ControllerSpec.harness_inputs``):

- **the buttons**: the red cap's top read from the base camera with its shipped calibration (``read_red_cap``, the
  progress writer's reader; 0.09-0.33 cm from the simulator's at development seeds 5000-5002) at the first frame
  that shows it (they stand still), and the black button where MIKASA stands it, 16 cm to the robot's left
  (``CONFIRM_OFFSET``, its ``CONFIRM_BUTTON_Y_OFFSET``);
- **the phase**: the phase lamp seen green in the base camera (``lamp_lit``, the cue writer's reader), once, for
  the rest of the episode (MIKASA keeps it green from the cue's end);
- **the hand's motion**: dead-reckoned from the hand's pose and the actions that ran (``DeadReckonedHand``, at the
  pace it declares, ``paced_every``); which way the hand goes, down to a press or up from one, is read from it.

The presses made so far come from its prompt's progress fact only (``progress_from="prompt"``), written by the
progress writer (written, recall) or from MIKASA's counter (oracle). It keeps per-env perception (the red cap's
place, whether the lamp was seen green, the hand's last position and step; ``reset``/``reset_envs`` clear it),
never the count: that reaches it through its prompt alone.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.blink_count.expert import ButtonPressController, PressGains, stated_presses
from sb3_memret.tasks.mikasa.blink_count.task import BUTTON_BASE_Z, lamp_lit, read_red_cap
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.hand_motion import DeadReckonedHand
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT, TouchGains

CONFIRM_OFFSET = np.array([0.0, 0.16, 0.0])  # MIKASA's CONFIRM_BUTTON_Y_OFFSET: the black button from the red one
GREEN = 1  # lamp_lit's channel of the phase lamp's green


def base_camera_red_cap(rgb: Any) -> np.ndarray | None:
    """``read_red_cap`` of one base-camera frame with the camera's shipped calibration."""
    return read_red_cap(np.asarray(as_numpy(rgb)), BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC)


def base_camera_green(rgb: Any) -> bool:
    """Whether one base-camera frame shows the phase lamp green."""
    return lamp_lit(np.asarray(as_numpy(rgb)), GREEN)


class CameraButtonPressController(ButtonPressController):
    """Presses the red button as often as its prompt's count, then the black one, once the phase lamp is green,
    reading only the base camera's image and the hand's pose (the module docstring says how). ``paced_every``: the
    control steps executed between its calls; ``read_cap`` (image -> the red cap's table (x, y), or None) and
    ``read_green`` (image -> the phase lamp green) default to the base camera's readers."""

    def __init__(self, prompt_template: PromptTemplate, paced_every: int, default_count: int = 1,
                 chunk_len: int = 8, gains: TouchGains | None = None, press_gains: PressGains | None = None,
                 read_cap: Callable[[Any], np.ndarray | None] | None = None,
                 read_green: Callable[[Any], bool] | None = None):
        super().__init__(prompt_template, default_count, chunk_len, gains, press_gains, progress_from="prompt")
        self.hand = DeadReckonedHand(paced_every, chunk_len)
        self.spec = dataclasses.replace(self.spec, needs_images=True, harness_inputs=True)
        self.stateful = True  # its perception: the red cap, the lamp seen green, the hand's motion (never the count)
        self.paced_every = paced_every
        self.read_cap, self.read_green = read_cap or base_camera_red_cap, read_green or base_camera_green
        self.caps: list[np.ndarray | None] = []
        self.green: list[bool] = []

    def reset(self, seeds: Sequence[int]) -> None:
        super().reset(seeds)
        self.caps, self.green = [None] * len(seeds), [False] * len(seeds)
        self.hand.reset(len(seeds))

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        super().reset_envs(env_ids, seeds)
        for i in env_ids:
            self.caps[i], self.green[i] = None, False
            self.hand.reset_env(i)

    def reads_images(self) -> bool:
        """Until every env has placed its red cap and seen the lamp green: nothing else is read."""
        return not self.caps or not all(cap is not None and green for cap, green in zip(self.caps, self.green))

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        tcp = as_numpy(obs["extra"]["tcp_pose"]).astype(np.float64)
        steps = self.hand.steps(tcp[:, :3])
        rgb = obs["sensor_data"]["base_camera"]["rgb"]
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            if self.caps[i] is None:
                cap = self.read_cap(rgb[i])
                self.caps[i] = None if cap is None else np.asarray(cap, dtype=np.float64)
            if not self.green[i]:
                self.green[i] = bool(self.read_green(rgb[i]))
            if self.caps[i] is None:
                continue  # the red button not yet in sight: hold still
            red = np.array([*self.caps[i], BUTTON_BASE_Z])
            rising = float(steps[i, 2]) / CONTROL_DT  # m/s, as the detector's version reads it from the joints
            goal = self._stateless_goal(stated_presses(p), self.count_of(p), tcp[i, :3], rising,
                                        np.stack([red, red + CONFIRM_OFFSET]), self.green[i])
            chunks[i] = self._chunk(tcp[i], steps[i], goal)
        self.hand.ran(tcp[:, :3], steps, chunks)
        return chunks


__all__ = ["CONFIRM_OFFSET", "CameraButtonPressController", "base_camera_green", "base_camera_red_cap"]
