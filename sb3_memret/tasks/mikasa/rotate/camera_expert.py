"""Rotate's peg-turning expert on what MIKASA's harness gives a policy alone: a protocol entry, not an upper bound.

``PegTurnController`` reads the peg's centre and axis from a simulated detector and the arm's joints (their
velocities, the wrist's angle), so its rows are a privileged upper bound. ``CameraPegTurnController`` is the same plan
and motion on the harness's inputs only (``ControllerSpec.harness_inputs``):

- **the peg**: its top face in the base camera at every call, cast onto the face's plane through the shipped
  calibration, its centre and axis those of the smallest rectangle round the cast pixels (``read_peg``: 0.6 degrees
  off the simulator's on average along development episodes, against 2.0 for the pixels' principal axis, which a
  finger over one side of the face tilts by up to 12 degrees). A frame that shows ``WHOLE_FRACTION`` of the face it showed at
  first sight gives its centre and axis, and so does one that shows both its ends (the fingers over its middle: the
  centre is between the ends). While the hand pushes, it hides the end it pushes: with the fingers down at the
  face, a frame that still shows a strip of the face's full width at least ``MIN_STRIP`` long gives the axis (its
  angle reads within 2 degrees), and the strip's end away from the hand is the peg's far end, so the centre is half
  the peg's length in from it (with the hand higher up, the arm may hide any part of the face, and a strip's ends
  are no ends). A frame
  that shows less (a thin or short strip, cut across by the fingers, read up to 21 degrees off) is not read, and the
  last reading stands, pushed on where the closed fingers now stand inside it, away from the side they came from
  (``pushed_peg``: the arm can hide the whole peg for several calls of a push, and the fingers can pass the axis
  last read);
- **the peg in hand** (Strict's grasp): its centre under the hand; its angle read as above where the frame shows it,
  else turned with the hand from its last reading (``PegInHand``);
- **the wrist's angle** (the grasp must leave the last joint room for the turn): dead-reckoned from the hand's pose
  (``WristEstimate``): pointing down, the hand's yaw is the base joint's angle minus the wrist's, plus a constant
  fixed at the reset, where the wrist starts at the Panda's rest angle;
- **the hand's motion**: dead-reckoned from the hand's pose and the actions that ran (``DeadReckonedHand``).

The rotation comes from its prompt's instruction and the start from its prompt's fact, as for the detector's version.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.harness_expert import HarnessExpert
from sb3_memret.tasks.mikasa.core.layout_perception import table_points
from sb3_memret.tasks.mikasa.rotate.expert import (
    GRIP_CLOSED, PEG_HALF_LENGTH, PEG_HALF_WIDTH, PegTurnController, TurnGains, hand_yaw, remaining_turn, wrap,
)
from sb3_memret.tasks.mikasa.rotate.task import PEG_TOP_Z, peg_on_table, peg_top_mask

PEG_CENTRE_Z = PEG_TOP_Z / 2  # the peg lies on the table
WHOLE_FRACTION = 0.85  # a frame showing this share of the top face's pixels at first sight shows the whole peg
MIN_STRIP = 0.1  # m: a part of the 24 cm top face this long ...
MIN_DENSITY = 0.65  # ... with this share of the whole face's pixels per metre (its full width) gives the peg's axis
STRIP_HAND_Z = PEG_TOP_Z + 0.03  # m: ... while the TCP is this low (the fingers, at the face, hide its near end;
# the arm above it hides any part, and a strip's far end is then no end: 11 cm off at development seeds)
# a push the arm hides turns the peg this much per metre the fingers went into its face, and slides it this share of
# that depth (least squares over 62 calls of pushes 2+ cm deep, development seeds 5000-5029: RMS 2 degrees a call;
# lab/2026-12-06-rotate-hidden-push); the plan's ``TurnGains.turn_per_metre`` (6) sizes a push, not this
HIDDEN_TURN_PER_METRE = 5.1
HIDDEN_SLIDE = 0.7
EDGE = 0.002  # m: a sighting's ends sit this far in from the face's (pixel centres; the whole face reads 23.6 cm)
ARM_BASE_XY = (-0.615, 0.0)  # where MIKASA mounts the arm (every task: ``set_root_pose``)
REST_WRIST = np.pi / 4  # the Panda's rest angle of its last joint; MIKASA's reset adds at most a few hundredths


@dataclasses.dataclass
class PegSighting:
    """One reading of the peg from the base camera: the centre (x, y) of the top face it shows, its axis's angle
    (radians in [0, pi)), how many top-face pixels it came from, and the (2, 2) ends (x, y) of the strip they span."""

    centre: np.ndarray
    yaw: float
    pixels: int
    ends: np.ndarray

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.ends[1] - self.ends[0]))

    @property
    def density(self) -> float:
        return self.pixels / max(self.length, 1e-9)


def read_peg(rgb: Any) -> PegSighting | None:
    """The peg in one base-camera frame (H, W, 3) through the shipped calibration; None when out of sight (the
    writer's reader, ``peg_on_table``, says when). Its centre and axis are the smallest rectangle's round the top
    face's pixels cast onto the face's plane: a hidden strip of one long side leaves the rectangle's other side."""
    frame = np.asarray(as_numpy(rgb))
    if peg_on_table(frame, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC) is None:
        return None
    mask = peg_top_mask(frame)
    points = table_points(np.argwhere(mask) + 0.5, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC, PEG_TOP_Z)
    (cx, cy), (width, height), degrees = cv2.minAreaRect(points.astype(np.float32))
    yaw = float(np.radians(degrees if width >= height else degrees + 90.0) % np.pi)
    centre = np.array([cx, cy], dtype=np.float64)
    axis = np.array([np.cos(yaw), np.sin(yaw)])
    along = (points - centre) @ axis
    return PegSighting(centre, yaw, int(mask.sum()), centre + np.outer([along.min(), along.max()], axis))


def pushed_peg(peg: PegSighting, hand: np.ndarray, gains: TurnGains, side: float | None = None) -> PegSighting:
    """The peg as the closed fingers at ``hand`` (x, y) must have pushed it since ``peg`` was read: fingers cannot
    stand inside it, so where they would, the face they touch has gone on by that depth. ``side``: the side of the
    peg's axis (+1 along its normal, -1 against) the fingers came from, pressing towards the other; by default the
    side they stand on (fingers that crossed the read axis came from the other side: the peg went on ahead of them).
    The push turns the peg ``HIDDEN_TURN_PER_METRE`` per metre of depth about its centre, the way the lever arm
    says, and slides it ``HIDDEN_SLIDE`` of the depth (both measured); fingers outside its face leave it as read."""
    axis = np.array([np.cos(peg.yaw), np.sin(peg.yaw)])
    normal = np.array([-axis[1], axis[0]])
    along, across = float((hand - peg.centre) @ axis), float((hand - peg.centre) @ normal)
    side = (1.0 if across >= 0 else -1.0) if side is None else side
    depth = PEG_HALF_WIDTH + gains.finger - side * across
    if depth <= 0 or abs(along) > PEG_HALF_LENGTH:
        return peg
    turn = -side * float(np.sign(along)) * HIDDEN_TURN_PER_METRE * depth  # (the +axis end pushed along +normal: +)
    centre = peg.centre - side * HIDDEN_SLIDE * depth * normal
    yaw = float((peg.yaw + turn) % np.pi)
    ends = centre + np.outer([-PEG_HALF_LENGTH + EDGE, PEG_HALF_LENGTH - EDGE], [np.cos(yaw), np.sin(yaw)])
    return PegSighting(centre, yaw, peg.pixels, ends)


def side_of(peg: PegSighting, hand: np.ndarray, gains: TurnGains) -> float | None:
    """The side of ``peg``'s axis (+1 along its normal, -1 against) that closed fingers at ``hand`` (x, y) stand on
    clear of its face, where a push from them would start; None where they would stand inside it."""
    across = float((hand - peg.centre) @ np.array([-np.sin(peg.yaw), np.cos(peg.yaw)]))
    return None if abs(across) < PEG_HALF_WIDTH + gains.finger else float(np.sign(across))


class WristEstimate:
    """Each env's last-joint angle from the hand's pose alone. Pointing down, the hand's yaw is the base joint's angle
    (the arm's plane through the TCP) minus the wrist's plus a constant; the constant is fixed at an episode's first
    call, where the wrist is at the Panda's rest angle."""

    def __init__(self) -> None:
        self.offsets: list[float | None] = []
        self.yaws: list[float] = []

    def reset(self, n_envs: int) -> None:
        self.offsets, self.yaws = [None] * n_envs, [0.0] * n_envs

    def reset_env(self, i: int) -> None:
        self.offsets[i] = None

    def angle(self, i: int, tcp: np.ndarray) -> float:
        """Env ``i``'s wrist angle (radians) from its TCP pose (x, y, z, qw, qx, qy, qz); the hand's yaw is unwrapped
        from call to call, so a turn past +-180 degrees keeps counting."""
        base = float(np.arctan2(tcp[1] - ARM_BASE_XY[1], tcp[0] - ARM_BASE_XY[0]))
        yaw = hand_yaw(Rotation.from_quat(tcp[[4, 5, 6, 3]]))
        if self.offsets[i] is None:
            self.offsets[i], self.yaws[i] = REST_WRIST - base + yaw, yaw
        self.yaws[i] += float(wrap(yaw - self.yaws[i], 2 * np.pi))
        return base - self.yaws[i] + self.offsets[i]


class PegInHand:
    """Each env's peg while gripped: its angle against the hand's, fixed at the grip; ``None`` while not held."""

    def __init__(self) -> None:
        self.offsets: list[float | None] = []

    def reset(self, n_envs: int) -> None:
        self.offsets = [None] * n_envs

    def reset_env(self, i: int) -> None:
        self.offsets[i] = None

    def track(self, i: int, gripped: bool, near: bool, hand: float, yaw: float, fresh: bool) -> float | None:
        """The peg's axis angle now (radians in [0, pi)) while held: gripped (the fingers' gap on the peg's width)
        and either already held or with the hand at the peg last seen; None (and the grip forgotten) otherwise.
        ``yaw``: the peg's angle as last read, ``fresh`` when read from this call's frame: then it stands, and fixes
        the peg's angle against the hand (fingers closing on it turn it a few degrees); else the peg turns with the
        hand from its last fix, seen or not."""
        if not gripped or (self.offsets[i] is None and not near):
            self.offsets[i] = None
            return None
        if fresh or self.offsets[i] is None:
            self.offsets[i] = float(wrap(yaw - hand))
        return float((hand + self.offsets[i]) % np.pi)


class CameraPegTurnController(HarnessExpert, PegTurnController):
    """Turns the peg to ``start + rotation`` as ``PegTurnController`` does, reading only the base camera's image, the
    hand's pose and the gripper's opening (the module docstring says how). ``paced_every``: the control steps
    executed between its calls; ``read``: image -> a ``PegSighting`` or None (the base camera's reader by default)."""

    def __init__(self, prompt_template: PromptTemplate, strategy: str, default_start_deg: float, paced_every: int,
                 chunk_len: int = 8, gains: TurnGains | None = None,
                 read: Callable[[Any], PegSighting | None] = read_peg):
        super().__init__(prompt_template, strategy, default_start_deg, chunk_len, gains)
        self._on_harness(paced_every, chunk_len)
        self.read = read
        self.wrist = WristEstimate()
        self.in_hand = PegInHand()
        self.pegs: list[PegSighting | None] = []  # each env's peg as it now reads it
        self.wholes: list[PegSighting | None] = []  # ... and its fullest sighting of the whole face
        self.sides: list[float | None] = []  # ... and the side of it the fingers last stood on clear of its face

    def _forget(self, n_envs: int) -> None:
        self.pegs, self.wholes, self.sides = [None] * n_envs, [None] * n_envs, [None] * n_envs
        self.wrist.reset(n_envs)
        self.in_hand.reset(n_envs)

    def _forget_env(self, i: int) -> None:
        self.pegs[i], self.wholes[i], self.sides[i] = None, None, None
        self.wrist.reset_env(i)
        self.in_hand.reset_env(i)

    def reads_images(self) -> bool:
        """Always: the peg moves as it is turned."""
        return True

    def _see(self, i: int, rgb: Any, hand: np.ndarray) -> bool:
        """Env ``i``'s peg from one frame, the TCP at ``hand`` (x, y, z): the whole face sets it, a strip of the
        face's width its axis and its far end while the fingers are down at it (the module docstring says why).
        Whether the frame was read."""
        seen, whole = self.read(rgb), self.wholes[i]
        if seen is None:
            return False
        if whole is None or seen.pixels >= WHOLE_FRACTION * whole.pixels:
            self.wholes[i] = seen if whole is None or seen.pixels > whole.pixels else whole
            self.pegs[i] = seen
            return True
        if seen.length >= WHOLE_FRACTION * whole.length:  # both ends in sight, the hand over its middle
            self.pegs[i] = PegSighting(seen.ends.mean(axis=0), seen.yaw, seen.pixels, seen.ends)
            return True
        if seen.length >= MIN_STRIP and seen.density >= MIN_DENSITY * whole.density and hand[2] < STRIP_HAND_Z:
            far, near = sorted(seen.ends, key=lambda end: -float(np.linalg.norm(end - hand[:2])))
            inward = (near - far) / max(float(np.linalg.norm(near - far)), 1e-9)
            centre = far + (PEG_HALF_LENGTH - EDGE) * inward
            self.pegs[i] = PegSighting(centre, seen.yaw, seen.pixels, np.stack([far, centre + (centre - far)]))
            return True
        return False

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        g = self.gains
        inputs = self._harness_inputs(obs, len(prompts))
        tcp, gaps, steps, rgb = inputs
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        chunks[:, :, -1] = GRIP_CLOSED
        for i, p in enumerate(parsed):
            wrist = self.wrist.angle(i, tcp[i])
            fresh = self._see(i, rgb[i], tcp[i, :3])
            peg = self.pegs[i]
            if peg is None:
                continue  # the peg not yet in sight: hold still
            if self.strategy == "push":
                if not fresh and tcp[i, 2] < g.push_z + 0.02:  # the arm hides the peg it pushes
                    peg = self.pegs[i] = pushed_peg(peg, tcp[i, :2], g, self.sides[i])
                side = side_of(peg, tcp[i, :2], g)
                self.sides[i] = side if side is not None or tcp[i, 2] >= STRIP_HAND_Z else self.sides[i]
            centre, yaw = np.array([*peg.centre, PEG_CENTRE_Z]), peg.yaw
            hand = hand_yaw(Rotation.from_quat(tcp[i, [4, 5, 6, 3]]))
            gripped = self.strategy == "grasp" and g.held_gap[0] <= gaps[i] <= g.held_gap[1]
            near = np.linalg.norm(tcp[i, :2] - centre[:2]) <= g.held_reach
            in_hand = self.in_hand.track(i, gripped, bool(near), hand, yaw, fresh)
            if in_hand is not None:
                centre, yaw = np.array([*tcp[i, :2], tcp[i, 2]]), in_hand
            rotation, start = self.goal_of(p)
            left = remaining_turn(start + rotation, yaw, rotation)
            if abs(left) <= g.done:
                continue  # there: hold still
            joints = np.full(9, np.nan)
            joints[6], joints[7], joints[8] = wrist, gaps[i] / 2, gaps[i] / 2
            plan = self._grasp_plan if self.strategy == "grasp" else self._push_plan
            chunks[i] = self._chunk(tcp[i], steps[i], plan(tcp[i], centre, yaw, left, joints))
        return self._ran(inputs, chunks)


__all__ = ["CameraPegTurnController", "PegInHand", "PegSighting", "WristEstimate", "pushed_peg", "read_peg", "side_of"]
