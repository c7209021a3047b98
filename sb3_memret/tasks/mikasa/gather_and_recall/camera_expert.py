"""GatherAndRecall's gather-and-press expert on what MIKASA's harness gives a policy alone: a protocol entry, not an
upper bound.

``GatherPressController`` reads every cube's, the disc's and the buttons' positions from a simulated detector and the
arm's joint velocities, so its rows are a privileged upper bound. ``CameraGatherPressController`` plays the same plan
and motion on the harness's inputs only (``ControllerSpec.harness_inputs``), from the first frame that shows the
whole layout:

- **the cubes**: the red, green and blue blobs on the robot's right (MIKASA stands them at y = -26 cm, rows 9 cm
  apart; the buttons' caps, of the same colours, stand beyond y = -4 cm), each cast onto the plane of a cube's centre
  through the shipped calibration (``read_layout``), numbered row by row as MIKASA numbers them; then each carried by
  the hand while gripped and left where it was let go (``HeldCubes``);
- **the buttons**: the three caps in a row on the robot's left, by colour (``CAP_PIXELS_Z`` says where they are cast);
- **the disc**: where MIKASA lays it from the buttons (22 cm beyond their row, in line with the middle one): the
  disc's own grey is the robot's and the floor's;
- **the hand's motion**: dead-reckoned from the hand's pose and the actions that ran (``DeadReckonedHand``).

The colour to press comes from its prompt alone, as for the detector's version.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Sequence

import numpy as np
from scipy import ndimage

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.carry_expert import CarryGains
from sb3_memret.tasks.mikasa.core.harness_expert import HarnessExpert
from sb3_memret.tasks.mikasa.core.layout_perception import table_points
from sb3_memret.tasks.mikasa.core.perception import REFERENCE_SIZE
from sb3_memret.tasks.mikasa.gather_and_recall.expert import GatherGains, GatherPressController

CUBE_CENTRE_Z = 0.02  # a 4 cm cube standing on the table
BUTTON_BASE_Z = 0.015  # the detector's button point: its base's centre
CAP_PIXELS_Z = 0.045  # a cap's pixels (its top and the side facing the camera) are cast onto this plane: within
# 0.3 cm of its axis at development seeds 5000-5007, where its top's plane (5.8 cm) put them 1.2 cm toward the camera
DISC_FROM_BUTTONS = 0.22  # MIKASA lays the disc this far beyond the buttons' row (x), in line with the middle one
DISC_Z = 0.003
SIDE_Y = -0.10  # cubes stand on the robot's right of this (y), the buttons on its left
ROW_PITCH = 0.09  # MIKASA's cube rows and columns
MIN_BLOB_PIXELS = 4  # at 128x128: a cube shows 12-30 pixels, a cap 10-20
# the cubes' and caps' lit shades, by colour: (channel, the least it reaches, the most the other two reach)
COLOUR_CHANNELS = {"red": (0, 110, 70), "green": (1, 110, 90), "blue": (2, 110, 90)}


class Layout(NamedTuple):
    """One frame's reading of the table: the cubes' (n, 3) centres in MIKASA's order, the buttons' bases (3, 3) in
    the prompt's colour order, and the disc's centre (3,)."""

    cubes: np.ndarray
    buttons: np.ndarray
    disc: np.ndarray


def _blobs(frame: np.ndarray, colour: str, plane_z: float) -> list[np.ndarray]:
    """The table (x, y) of every blob of ``colour`` in one frame, cast onto ``z = plane_z``."""
    channel, least, others = COLOUR_CHANNELS[colour]
    rest = [c for c in range(3) if c != channel]
    mask = (frame[..., channel] >= least) & np.all(frame[..., rest] <= others, axis=-1)
    mask &= frame[..., channel] - frame[..., rest].max(axis=-1) >= 60
    labels, n_blobs = ndimage.label(mask, structure=np.ones((3, 3)))
    least_pixels = MIN_BLOB_PIXELS * np.prod(np.array(mask.shape) / REFERENCE_SIZE)
    centres = [np.argwhere(labels == k).mean(axis=0) + 0.5 for k in range(1, n_blobs + 1)
               if (labels == k).sum() >= least_pixels]
    if not centres:
        return []
    points = table_points(np.array(centres), BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC, plane_z)
    return [point for point in points if np.isfinite(point).all()]


def read_layout(rgb: Any, n_cubes: int, colours: Sequence[str]) -> Layout | None:
    """The cubes, the buttons (one per colour of ``colours``) and the disc from one base-camera frame; None unless it
    shows exactly ``n_cubes`` cubes and one cap of each colour."""
    frame = np.asarray(as_numpy(rgb)).astype(np.int16)
    cubes, buttons = [], []
    for colour in colours:
        caps = [p for p in _blobs(frame, colour, CAP_PIXELS_Z) if p[1] > SIDE_Y]
        if len(caps) != 1:
            return None
        buttons.append([*caps[0], BUTTON_BASE_Z])
        cubes += [p for p in _blobs(frame, colour, CUBE_CENTRE_Z) if p[1] <= SIDE_Y]
    if len(cubes) != n_cubes:
        return None
    cubes = np.array(cubes)
    rows = np.round((cubes[:, 1] - cubes[:, 1].min()) / ROW_PITCH)
    cubes = cubes[np.lexsort((cubes[:, 0], rows))]  # MIKASA's order: row by row, each from the robot outward
    buttons = np.array(buttons)
    disc = np.array([buttons[:, 0].mean() + DISC_FROM_BUTTONS, buttons[len(buttons) // 2, 1], DISC_Z])
    return Layout(np.column_stack([cubes, np.full(n_cubes, CUBE_CENTRE_Z)]), buttons, disc)


class HeldCubes:
    """One env's cubes as far as it knows: placed where first seen, the one the fingers close on (the hand within
    reach of it) carried at its offset from the hand, left where it was carried to when let go."""

    def __init__(self, carry: CarryGains, places: np.ndarray):
        self.carry = carry
        self.places = np.asarray(places, dtype=np.float64).copy()
        self.held: int | None = None
        self.offset = np.zeros(3)

    def track(self, tcp: np.ndarray, gap: float) -> np.ndarray:
        """The (n, 3) cubes now, the hand at ``tcp`` with the fingers ``gap`` apart."""
        c = self.carry
        if not c.held_gap[0] <= gap <= c.held_gap[1]:
            self.held = None
        elif self.held is None:
            reach = np.linalg.norm(self.places - tcp, axis=1)
            if reach.min() <= c.held_reach:
                self.held = int(reach.argmin())
                self.offset = tcp - self.places[self.held]
        if self.held is not None:
            self.places[self.held] = tcp - self.offset
        return self.places.copy()


class CameraGatherPressController(HarnessExpert, GatherPressController):
    """Puts every cube on the disc, then presses the button of its prompt's colour, reading only the base camera's
    image, the hand's pose and the gripper's opening (the module docstring says how). ``n_cubes``: the task's;
    ``paced_every``: the control steps executed between its calls; ``read``: image -> a ``Layout`` or None."""

    def __init__(self, prompt_template: PromptTemplate, vocabulary: Sequence[str], default: str, n_cubes: int,
                 paced_every: int, chunk_len: int = 8, carry: CarryGains | None = None,
                 gather: GatherGains | None = None, read: Callable[[Any], Layout | None] | None = None):
        super().__init__(prompt_template, vocabulary, default, chunk_len, carry=carry, gather=gather)
        self._on_harness(paced_every, chunk_len)
        self.n_cubes = n_cubes
        self.read = read or (lambda rgb: read_layout(rgb, n_cubes, self.vocabulary))
        self.layouts: list[Layout | None] = []
        self.cubes: list[HeldCubes | None] = []

    def _forget(self, n_envs: int) -> None:
        self.layouts, self.cubes = [None] * n_envs, [None] * n_envs

    def _forget_env(self, i: int) -> None:
        self.layouts[i] = self.cubes[i] = None

    def reads_images(self) -> bool:
        """Until every env has read its layout: the hand then carries what it knows."""
        return not self.layouts or any(layout is None for layout in self.layouts)

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        inputs = self._harness_inputs(obs, len(prompts))
        tcp, gaps, steps, rgb = inputs
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            if self.layouts[i] is None:
                self.layouts[i] = self.read(rgb[i])
                if self.layouts[i] is None:
                    continue  # the layout not yet read whole: hold still
                self.cubes[i] = HeldCubes(self.carry, self.layouts[i].cubes)
            layout = self.layouts[i]
            cubes = self.cubes[i].track(tcp[i, :3], float(gaps[i]))
            button = layout.buttons[self.vocabulary.index(self.colour_of(p))]
            chunks[i] = self._chunk(tcp[i], steps[i], self._goal(tcp[i, :3], cubes, float(gaps[i]), layout.disc, button))
        return self._ran(inputs, chunks)


__all__ = ["CameraGatherPressController", "HeldCubes", "Layout", "read_layout"]
