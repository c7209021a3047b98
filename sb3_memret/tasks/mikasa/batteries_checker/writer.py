"""BatteriesChecker's checklist writer: which battery went through a complete check and whether the lamp lit, read
from the base camera and the arm's own sensors only.

What it reads (``CheckPercept``, one per control step):

- from the base camera with its shipped calibration (``core.calibration``): where the batteries stand at the
  episode's start (``read_batteries``: the green blobs of their tops, cast onto the plane of their tops; their order
  is MIKASA's, row by row from the robot's right, each row from the camera's side: battery i stands in slot i + 1),
  where the button is (``read_button``: its pink cap's top face), and whether the lamp is lit (``lamp_lit``: the
  lit bulb renders as a blob of pure white, 80-84 pixels at 128x128; the white arm's highlights reach 12);
- from the arm: the TCP's position and the fingers' gap (what MIKASA's harness hands a policy as proprioception).

A check, as MIKASA's env counts one, and as the writer follows it: the fingers close on a battery at its slot
(the TCP within ``CheckRule.at_slot`` of it, low); they open again away from the tray (the battery let go into the
socket, where the env seats it and, for a working one, lights the lamp); on Hard the fingers then close on it
again and open over its slot (it is back home); then the button is pressed (MIKASA's rule: the TCP within 7.5 cm
of the cap's axis and 2.51 cm over its top, the cap released in between). At that press the battery's slot joins
the checklist, ``working`` if the lamp was seen lit since it was picked up, else ``dead``, and the fact
``the battery check found slot 1 dead and slot 3 working.`` is written (replacing the last).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy import ndimage

from sb3_memret.memory.schema import MemoryType
from sb3_memret.tasks.base import EnvFrame, Predicates
from sb3_memret.tasks.mikasa.batteries_checker.checklist import CHECK_ENTITY, CHECK_RELATION, checklist_value
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.layout_perception import table_points

REFERENCE_PIXELS = 128 * 128  # the blob sizes below are measured at 128x128
BATTERY_TOP_Z = 0.06  # a standing battery's top (MIKASA: 6 cm tall, on the table)
BATTERY_SEEN_Z = 0.05  # its seen pixels (top face and camera-facing side) cast best onto this plane
MIN_BATTERY_PIXELS = 2  # a battery's top covers 3-6 pixels ...
MERGED_PIXELS = 9  # ... so a blob this large may be two tops
ROW_GAP = 0.026  # batteries whose y differ by less than this stand in one row (MIKASA's rows: 5.2 cm apart)
CAP_RGB = (209, 157, 157)  # the button cap's top face as the base camera renders it
CAP_TOL = 16
MIN_CAP_PIXELS = 12  # its top covers about 30 pixels
CAP_TOP_Z = 0.058  # the unpressed cap's top
MIN_LIT_PIXELS = 30  # the lit bulb: one blob of 80-84 pure white pixels


def _blobs(mask: np.ndarray, min_pixels: float) -> list[np.ndarray]:
    """The (k, 2) pixel coordinates (row, col) of each 8-connected blob of ``mask`` with at least ``min_pixels``."""
    labels, n = ndimage.label(mask, structure=np.ones((3, 3)))
    return [where for blob in range(1, n + 1) if len(where := np.argwhere(labels == blob)) >= min_pixels]


def _split_in_two(pixels: np.ndarray) -> list[np.ndarray]:
    """One blob's (k, 2) pixels as two: cut across its long axis where the two halves' spread is least (two tops
    that touch in the picture)."""
    centred = pixels - pixels.mean(axis=0)
    along = centred @ np.linalg.svd(centred, full_matrices=False)[2][0]
    order = np.argsort(along)
    ranked = along[order]
    cut = min(range(1, len(ranked)), key=lambda i: ranked[:i].var() * i + ranked[i:].var() * (len(ranked) - i))
    return [pixels[order[:cut]], pixels[order[cut:]]]


def _check_frame(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"expected one (H, W, 3) frame, got shape {rgb.shape}")
    return rgb.astype(np.int16)


def read_batteries(rgb: np.ndarray, count: int | None = None) -> np.ndarray:
    """The table (x, y) of every standing battery one base-camera frame (H, W, 3) shows, in MIKASA's slot order
    (rows by y, each row by x from the camera's side): (n, 2). With ``count`` (the batteries known to stand), a blob
    too large for one top is split in two, the largest first, while fewer are found: two batteries of one row,
    5 cm apart along the camera's line of sight, show their tops touching at some tray positions (development seeds
    5014 and 5015, BatteriesCheckerEasy-3)."""
    rgb = _check_frame(rgb)
    green = (rgb[..., 1] >= rgb[..., 0] + 40) & (rgb[..., 1] >= rgb[..., 2] + 30)
    scale = rgb.shape[0] * rgb.shape[1] / REFERENCE_PIXELS
    blobs = _blobs(green, MIN_BATTERY_PIXELS * scale)
    while count is not None and len(blobs) < count and blobs and max(map(len, blobs)) >= MERGED_PIXELS * scale:
        largest = blobs.pop(max(range(len(blobs)), key=lambda i: len(blobs[i])))
        blobs += _split_in_two(largest)
    if not blobs:
        return np.zeros((0, 2))
    centres = np.array([pixels.mean(axis=0) + 0.5 for pixels in blobs])
    points = table_points(centres, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC, BATTERY_SEEN_Z)
    rows = np.floor((points[:, 1] - points[:, 1].min()) / ROW_GAP + 0.5)
    return points[np.lexsort((-points[:, 0], rows))]


def read_button(rgb: np.ndarray) -> np.ndarray | None:
    """The button's table (x, y) from one base-camera frame (H, W, 3): its cap's top face (the largest blob of
    ``CAP_RGB``), cast onto the plane of the cap's top; None when not in sight."""
    rgb = _check_frame(rgb)
    mask = (np.abs(rgb - np.array(CAP_RGB, dtype=np.int16)) <= CAP_TOL).all(axis=-1)
    labels, n = ndimage.label(mask, structure=np.ones((3, 3)))
    if n == 0:
        return None
    sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    if sizes.max() < MIN_CAP_PIXELS * rgb.shape[0] * rgb.shape[1] / REFERENCE_PIXELS:
        return None
    centre = np.argwhere(labels == int(sizes.argmax()) + 1).mean(axis=0) + 0.5
    point = table_points(centre[None], BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC, CAP_TOP_Z)[0]
    return point if np.isfinite(point).all() else None


def lamp_lit(rgb: np.ndarray) -> bool:
    """Whether the lamp is lit in one base-camera frame (H, W, 3): a blob of at least ``MIN_LIT_PIXELS`` pure white
    pixels (all channels >= 250)."""
    rgb = _check_frame(rgb)
    white = (rgb >= 250).all(axis=-1)
    labels, n = ndimage.label(white, structure=np.ones((3, 3)))
    if n == 0:
        return False
    biggest = np.bincount(labels.ravel(), minlength=n + 1)[1:].max()
    return bool(biggest >= MIN_LIT_PIXELS * rgb.shape[0] * rgb.shape[1] / REFERENCE_PIXELS)


class CheckPercept(NamedTuple):
    """One control step as the writer reads it: the TCP (x, y, z) and the fingers' gap (the arm's sensors), whether
    the lamp is lit, and, where the camera shows them, the batteries' (x, y) in slot order and the button's."""

    tcp: tuple[float, float, float]
    gap: float
    lit: bool
    batteries: tuple[tuple[float, float], ...]
    button: tuple[float, float] | None


@dataclass(frozen=True)
class CheckRule:
    """How the writer follows a check (metres), MIKASA's thresholds where it has them."""

    held_gap: tuple[float, float] = (0.012, 0.019)  # fingers closed on a 2 cm battery
    open_gap: float = 0.025  # fingers open again
    at_slot: float = 0.015  # a grip this close (xy) to a slot takes that slot's battery ...
    low: float = 0.07  # ... with the TCP this low
    home: float = 0.023  # let go this close to its slot: it is back (MIKASA's SLOT_RETURN_XY_TOL)
    press_xy: float = 0.075  # MIKASA's press: the TCP this close to the cap's axis ...
    press_down: float = 0.0251  # ... and this close over its top (0.03 margin less 0.35 of the 1.4 cm travel)
    released: float = 0.0272  # the cap counts as released with the TCP this high over it (less 0.2 of the travel)


@dataclass
class _Check:
    """The check under way, as the writer follows it."""

    slot: int  # from 1
    tested: bool = False  # let go away from the tray (into the socket)
    regrasped: bool = False  # Hard: taken again after the test
    home: bool = False  # Hard: let go over its slot after the test
    lit: bool = False


@dataclass
class ChecklistWriter:
    """Writes the battery checklist (``checklist``'s one fact) at each press of the button that confirms a check
    (``hard``: the battery put back in its slot first); percepts are ``CheckPercept``s, one per control step, the
    reset frame's (``steps == 0``) starting an episode."""

    n_batteries: int
    hard: bool
    rule: CheckRule = field(default_factory=CheckRule)

    def __post_init__(self) -> None:
        self.relations = {"checked": (MemoryType.OTHER, CHECK_RELATION)}
        self._start_episode()

    def _start_episode(self) -> None:
        self.slots: np.ndarray | None = None
        self.button: np.ndarray | None = None
        self.check: _Check | None = None
        self.held, self.ready = False, True
        self.checks: dict[int, bool] = {}

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self._start_episode()
        out = []
        for step, percept in frame.timed_percepts():
            if not isinstance(percept, CheckPercept):
                raise ValueError(f"the checklist writer reads CheckPercepts (BatteriesCheckerTask.perceive); got "
                                 f"{percept!r}")
            if self._step(percept):
                out.append((step, {("checked", CHECK_ENTITY): checklist_value(self.checks)}))
        return out

    def _step(self, p: CheckPercept) -> bool:
        """Follow one control step; whether it confirmed a check."""
        r = self.rule
        if self.slots is None and len(p.batteries) == self.n_batteries:
            self.slots = np.asarray(p.batteries, dtype=np.float64)
        if self.button is None and p.button is not None:
            self.button = np.asarray(p.button, dtype=np.float64)
        if self.slots is None:
            return False
        tcp = np.asarray(p.tcp, dtype=np.float64)
        to_slots = np.linalg.norm(self.slots - tcp[None, :2], axis=1)
        closed = r.held_gap[0] <= p.gap <= r.held_gap[1]
        if closed and not self.held:  # a grip: a battery taken at its slot, or the one under test taken again
            at = int(to_slots.argmin())
            if to_slots[at] <= r.at_slot and tcp[2] <= r.low and (self.check is None or not self.check.tested):
                self.check = _Check(at + 1)
            elif self.check is not None and self.check.tested:
                self.check.regrasped = True
        elif self.held and p.gap >= r.open_gap and self.check is not None:  # let go
            near_home = to_slots[self.check.slot - 1] <= r.home
            if not self.check.tested and to_slots.min() > r.at_slot * 2:
                self.check.tested = True
            elif self.check.tested and self.check.regrasped and near_home:
                self.check.home = True
        self.held = closed or (self.held and p.gap < r.open_gap)
        if self.check is not None and self.check.tested:
            self.check.lit |= p.lit
        return self._pressed(tcp)

    def _pressed(self, tcp: np.ndarray) -> bool:
        """Whether this step presses the button and so confirms the check under way (MIKASA's press rule)."""
        r = self.rule
        if self.button is None:
            return False
        over = tcp[2] - CAP_TOP_Z if np.linalg.norm(tcp[:2] - self.button) <= r.press_xy else np.inf
        if over >= r.released:
            self.ready = True
            return False
        if not (self.ready and over <= r.press_down):
            return False
        self.ready = False
        check, self.check = self.check, None
        if check is None or not check.tested or (self.hard and not check.home):
            return False
        self.checks[check.slot] = check.lit
        return True


__all__ = ["CheckPercept", "CheckRule", "ChecklistWriter", "lamp_lit", "read_batteries", "read_button"]
