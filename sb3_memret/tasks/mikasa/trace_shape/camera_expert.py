"""TraceShape's and TraceShapeSeq's tracing experts on what MIKASA's harness gives a policy alone: protocol entries, not
upper bounds.

``TraceShapeController`` and ``TraceSequenceController`` read the green cube's (and the button's) position from a
simulated detector and the arm's joint velocities, so their rows are a privileged upper bound. The camera versions
play the same plan and motion on the harness's inputs only (``ControllerSpec.harness_inputs``):

- **the green cube**: its green pixels (top and front faces, about (90, 177, 90); not the lamp's lit green), their mean cast
  onto the plane of the cube's centre through the shipped calibration (``read_green_cube``: within 0.5 cm at
  development seeds 5000-5009 of both families, where the same pixels cast onto the top face's plane sat 1.4-2.4 cm
  toward the camera), carried by the hand while gripped (``HeldCube``, with the tracing grip's gap and reach), and
  read again wherever it stands clear of the hand or fell to, or once the fingers closed on nothing where it was
  placed (a cube slips from the fingers now and then: the detector's expert grasps it again where it lies, and so
  does this one, lifting the hand out of the camera's way first where the arm hides it). A cube just gripped is
  lifted straight to the carry height, measured, before the trace sets off sideways;
- **the button** (TraceShapeSeq): its cap's pink (about (208, 136, 136)), the largest such patch, cast onto the
  plane of the cap's centre (``read_button_cap``: within 0.8 cm of it, where MIKASA counts a press within 6.5 cm);
- **the hand's motion**: dead-reckoned from the hand's pose and the actions that ran (``DeadReckonedHand``).

The path (and, for the sequence, the progress) comes from the prompt alone, as for the detector's versions.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import numpy as np
from scipy import ndimage

from sb3_memret.controllers.base import Obs
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.carry_expert import CarryGains
from sb3_memret.tasks.mikasa.core.harness_expert import HarnessExpert
from sb3_memret.tasks.mikasa.core.held_object import HeldCube
from sb3_memret.tasks.mikasa.core.layout_perception import cast_mask, rgb_frame
from sb3_memret.tasks.mikasa.trace_shape.expert import TraceGains, TraceGoal, TraceShapeController, path_of
from sb3_memret.tasks.mikasa.trace_shape.sequence_expert import (
    PressGains, TraceSequenceController, paths_done, sequence_of)

CUBE_CENTRE_Z = 0.02  # the 4 cm cube standing on the table
CAP_CENTRE_Z = 0.044  # MIKASA's TraceShapeSeq button cap's centre, unpressed
MIN_PIXELS = {"cube": 6, "cap": 20}  # at 128x128: the far cube shows 12-19, the cap 41-56
CLEAR_OF_HAND = 0.06  # m sideways: a cube this far from the hand is read whole
FALLEN_ABOVE = 0.01  # m: a cube let go this far over the table fell: read where it lies ...
LOOK_POINT = (-0.05, 0.0, 0.3)  # ... from the hand up here (about the reset's), the arm out of the camera's way


def read_green_cube(rgb: Any) -> np.ndarray | None:
    """The green cube's table (x, y) from one base-camera frame; None when not in sight. Its green is lit, not
    emissive: red and blue stay near half its green, where the lamp's lit green has them near 0."""
    frame = rgb_frame(rgb)
    red, green, blue = frame[..., 0], frame[..., 1], frame[..., 2]
    mask = (green >= 120) & (green <= 230) & (green - red >= 60) & (green - blue >= 60) & (red >= 50) & (blue >= 50)
    return cast_mask(mask, CUBE_CENTRE_Z, MIN_PIXELS["cube"])


def read_button_cap(rgb: Any) -> np.ndarray | None:
    """The button cap's table (x, y) from one base-camera frame: the largest patch of its pink (the red cube's
    shades are darker); None when not in sight."""
    frame = rgb_frame(rgb)
    red, green, blue = frame[..., 0], frame[..., 1], frame[..., 2]
    labels, n_patches = ndimage.label((red >= 190) & (green >= 115) & (green <= 160) & (np.abs(green - blue) <= 12),
                                      structure=np.ones((3, 3)))
    if n_patches == 0:
        return None
    return cast_mask(labels == np.bincount(labels.ravel())[1:].argmax() + 1, CAP_CENTRE_Z, MIN_PIXELS["cap"])


class _CameraTracing(HarnessExpert):
    """What both camera tracers keep per env beyond the hand: the cube (seen, then carried, read again where it
    stands or fell)."""

    def _setup(self, paced_every: int, chunk_len: int, read_cube: Callable[[Any], np.ndarray | None]) -> None:
        self._on_harness(paced_every, chunk_len)
        self.read_cube = read_cube
        grip = dataclasses.replace(CarryGains(), held_gap=self.trace.held_gap, held_reach=self.trace.held_reach)
        self.cube = HeldCube(grip)
        self.lost: list[bool] = []

    def _forget(self, n_envs: int) -> None:
        self.cube.reset(n_envs)
        self.lost = [False] * n_envs

    def _forget_env(self, i: int) -> None:
        self.cube.reset_env(i)
        self.lost[i] = False

    def _goal(self, pos: np.ndarray, cube: np.ndarray, gap: float, path: Any) -> TraceGoal:
        """The detector's expert's goal, except that a cube just gripped is lifted straight to the carry height
        before the pursuit sets off sideways: measured, not predicted (a chunk that set off once its prediction had
        risen jerked the cube out of the fingers at 2-5 cm over the table)."""
        goal = super()._goal(pos, cube, gap, path)
        if goal.mode == "trace" and cube[2] < self.trace.carry_z - self.carry.lift_first:
            return TraceGoal(np.array([cube[0], cube[1], self.trace.carry_z]) + goal.hand, "hold")
        return goal

    def _cube_now(self, i: int, rgb: Any, tcp: np.ndarray, gap: float) -> np.ndarray | None:
        """Env ``i``'s cube now: carried while gripped; else read again wherever it stands clear of the hand, or
        wherever it fell to once let go in the air (``_looks_again``). None while not seen, or fallen out of sight."""
        if self.cube.places[i] is not None:
            self.cube.track(i, tcp, gap)  # the grip as the fingers are now: a cube that slipped out is let go
            if self.cube.grips[i] is None and gap < self.trace.held_gap[0]:
                self.lost[i] = True  # the fingers closed on nothing: the cube is not where it was placed
        if self._looks_again(i, tcp):
            seen = self.read_cube(rgb)
            if seen is not None:
                self.cube.places[i] = np.array([*seen, CUBE_CENTRE_Z])
                self.lost[i] = False
        place = self.cube.places[i]
        if place is None or self.lost[i] or (self.cube.grips[i] is None and place[2] > CUBE_CENTRE_Z + FALLEN_ABOVE):
            return None
        return self.cube.track(i, tcp, gap)

    def _look(self, i: int, tcp: np.ndarray, step: np.ndarray) -> np.ndarray:
        """A chunk for env ``i`` without a cube to act on: still until first seen; after it fell out of sight or was
        lost from the fingers (the arm between it and the camera), up to ``LOOK_POINT``, the arm clear of the table."""
        if self.cube.places[i] is None:
            return np.zeros((self.spec.chunk_len, self.spec.action_dim))
        return self._chunk(tcp, step, TraceGoal(np.asarray(LOOK_POINT), "hold"))

    def _looks_again(self, i: int, tcp: np.ndarray) -> bool:
        """Whether env ``i``'s cube is read from this frame: not yet seen, or lost (the fingers closed where it was
        placed and found nothing); or not gripped and either clear of the hand (``CLEAR_OF_HAND`` sideways: the
        fingers hide part of it when nearer) or last carried off the table (it slipped from the fingers and fell)."""
        place = self.cube.places[i]
        if place is None or self.lost[i]:
            return True
        if self.cube.grips[i] is not None:
            return False
        return bool(np.linalg.norm(place[:2] - tcp[:2]) > CLEAR_OF_HAND or place[2] > CUBE_CENTRE_Z + FALLEN_ABOVE)

    def reads_images(self) -> bool:
        """While some env's cube is not in hand: it is read again where it stands (or fell)."""
        return not self.cube.places or any(grip is None for grip in self.cube.grips)


class CameraTraceShapeController(_CameraTracing, TraceShapeController):
    """Carries the green cube round the path its prompt names, reading only the base camera's image, the hand's pose
    and the gripper's opening (the module docstring says how). ``paced_every``: the control steps executed between
    its calls."""

    def __init__(self, prompt_template: PromptTemplate, paced_every: int, chunk_len: int = 8,
                 trace: TraceGains | None = None, read_cube: Callable[[Any], np.ndarray | None] = read_green_cube):
        super().__init__(prompt_template, chunk_len, trace=trace)
        self._setup(paced_every, chunk_len, read_cube)

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        inputs = self._harness_inputs(obs, len(prompts))
        tcp, gaps, steps, rgb = inputs
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            cube = self._cube_now(i, rgb[i], tcp[i, :3], float(gaps[i]))
            if cube is None:
                chunks[i] = self._look(i, tcp[i], steps[i])
            else:
                chunks[i] = self._chunk(tcp[i], steps[i], self._goal(tcp[i, :3], cube, float(gaps[i]), path_of(p)))
        return self._ran(inputs, chunks)


class CameraTraceSequenceController(_CameraTracing, TraceSequenceController):
    """Carries the green cube round each path of its prompt's sequence in order, then presses the button, reading only
    the base camera's image, the hand's pose and the gripper's opening (the module docstring says how)."""

    def __init__(self, prompt_template: PromptTemplate, paced_every: int, chunk_len: int = 8,
                 trace: TraceGains | None = None, press: PressGains | None = None,
                 read_cube: Callable[[Any], np.ndarray | None] = read_green_cube,
                 read_button: Callable[[Any], np.ndarray | None] = read_button_cap):
        super().__init__(prompt_template, chunk_len, trace=trace, press=press)
        self._setup(paced_every, chunk_len, read_cube)
        self.read_button = read_button
        self.buttons: list[np.ndarray | None] = []

    def _forget(self, n_envs: int) -> None:
        super()._forget(n_envs)
        self.buttons = [None] * n_envs

    def _forget_env(self, i: int) -> None:
        super()._forget_env(i)
        self.buttons[i] = None

    def reads_images(self) -> bool:
        """While some env's cube is not in hand or its button is not yet seen."""
        return super().reads_images() or any(place is None for place in self.buttons)

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        inputs = self._harness_inputs(obs, len(prompts))
        tcp, gaps, steps, rgb = inputs
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            if self.buttons[i] is None:
                seen = self.read_button(rgb[i])
                self.buttons[i] = None if seen is None else np.array([*seen, CAP_CENTRE_Z])
            cube = self._cube_now(i, rgb[i], tcp[i, :3], float(gaps[i]))
            if cube is None:
                chunks[i] = self._look(i, tcp[i], steps[i])
                continue
            paths, done = sequence_of(p), paths_done(p)
            if paths is not None and done >= len(paths):
                if self.buttons[i] is None:
                    continue  # every path traced, the button not yet in sight: hold still
                goal = self._submit(tcp[i, :3], cube, float(gaps[i]), self.buttons[i])
            else:
                goal = self._goal(tcp[i, :3], cube, float(gaps[i]), None if paths is None else paths[done])
            chunks[i] = self._chunk(tcp[i], steps[i], goal)
        return self._ran(inputs, chunks)


__all__ = ["CameraTraceSequenceController", "CameraTraceShapeController", "read_button_cap", "read_green_cube"]
