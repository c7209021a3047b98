"""What the base camera sees of the cups and balls: pixels cast onto the table, blobs found, and cups followed through a
shuffle."""

from __future__ import annotations

import itertools
from typing import NamedTuple, Sequence

import numpy as np
from scipy import ndimage

from sb3_memret.tasks.mikasa.core.perception import REFERENCE_SIZE
from sb3_memret.tasks.mikasa.shell_game.variants import LAMP_COLOURS


BALL_RADIUS = 0.02  # m: a ball's centre lies this high (MIKASA's BALL_RADIUS)

CUP_PLANE_Z = 0.05  # m: a cup's pixels are cast onto this plane, about its centre (estimated, see above)

BALL_MIN_LEVEL = 60  # a ball pixel's own channel is at least this ...

BALL_MAX_RATIO = 0.25  # ... and each other channel at most this share of it (the table's wood: >= 0.34, measured)

MIN_BALL_PIXELS = 3  # a ball covers ~14 pixels at 128x128

CHANGE_LEVEL = 40  # a pixel changed when a channel moved by more than this since the reference frame (estimated)

MIN_CUP_PIXELS = 40  # a mug covers ~70-300 pixels at 128x128 (estimated); the lamp's bulb ~25, a finger's twitch less

MAX_CUP_AREA = 4.0  # a changed blob this many times the largest mug at the first sighting is no single mug

MAX_CUP_STEP = 0.45  # m a cup may move between two read frames: across the widest swap (40 cm) and the cast's error

REST_TOL = 0.03  # m from a place in the row: the cup rests there

IDLE_TOL = 0.08  # m a cup may seem to move while it stands: MIKASA lifts all three during a swap (6 cm at most), and

#   the cast onto the plane puts a lifted cup up to ~6 cm nearer the robot
MID_TOL = 0.04  # m a swapping pair's midpoint may seem to move (the lift's shift differs a little across the row)

MAX_TURN = 0.9 * np.pi  # the most a swapping pair may turn between two read frames (a few merged frames skipped)

class CameraFrame(NamedTuple):
    """One base-camera frame and the camera's calibration: what the writer reads of a control step."""

    rgb: np.ndarray  # (H, W, 3) uint8
    intrinsic: np.ndarray  # (3, 3) OpenCV
    extrinsic: np.ndarray  # (3, 4) world to camera, OpenCV axes



def table_point(pixel: Sequence[float], intrinsic: np.ndarray, extrinsic: np.ndarray,
                plane_z: float) -> np.ndarray | None:
    """The world (x, y) where the camera ray through ``pixel`` (row, col, continuous: a pixel's centre is its index
    + 0.5) meets the plane ``z = plane_z``, or None when it does not (looking away from it)."""
    rotation, translation = np.asarray(extrinsic)[:, :3], np.asarray(extrinsic)[:, 3]
    ray = rotation.T @ (np.linalg.inv(np.asarray(intrinsic)) @ np.array([pixel[1], pixel[0], 1.0]))
    origin = -rotation.T @ translation
    if abs(ray[2]) < 1e-9 or (plane_z - origin[2]) / ray[2] <= 0:
        return None
    return (origin + (plane_z - origin[2]) / ray[2] * ray)[:2]



def _scale(rgb: np.ndarray) -> float:
    """Pixel counts measured at 128x128, scaled to this frame's size."""
    return rgb.shape[0] * rgb.shape[1] / REFERENCE_SIZE ** 2



def ball_mask(rgb: np.ndarray, colour: str) -> np.ndarray:
    """Pixels of the ``colour`` ball (red, green, blue: MIKASA's pure colours on a shaded sphere)."""
    if colour not in LAMP_COLOURS:
        raise ValueError(f"unknown ball colour {colour!r}; expected one of {list(LAMP_COLOURS)}")
    rgb = np.asarray(rgb).astype(np.int16)
    own = rgb[..., LAMP_COLOURS.index(colour)]
    others = np.delete(rgb, LAMP_COLOURS.index(colour), axis=-1).max(axis=-1)
    return (own >= BALL_MIN_LEVEL) & (others <= BALL_MAX_RATIO * own)



def ball_on_table(seen: CameraFrame, colour: str) -> np.ndarray | None:
    """Where the ``colour`` ball lies (its centre's x, y), or None when it is out of sight."""
    mask = ball_mask(seen.rgb, colour)
    if mask.sum() < MIN_BALL_PIXELS * _scale(seen.rgb):
        return None
    return table_point(np.argwhere(mask).mean(axis=0) + 0.5, seen.intrinsic, seen.extrinsic, BALL_RADIUS)



def cups_on_table(seen: CameraFrame, reference: np.ndarray, max_pixels: float = np.inf) -> list[tuple[np.ndarray, int]]:
    """The cups in sight, as (x, y) on the table and pixel count: the blobs of pixels that changed since
    ``reference`` (a frame of the same view before the cups came down) with at least ``MIN_CUP_PIXELS`` and at
    most ``max_pixels`` pixels, each blob's centre cast onto the plane about a cup's centre."""
    rgb, reference = np.asarray(seen.rgb), np.asarray(reference)
    if rgb.shape != reference.shape:
        raise ValueError(f"the frame {rgb.shape} and its reference {reference.shape} differ in shape")
    changed = np.abs(rgb.astype(np.int16) - reference.astype(np.int16)).max(axis=-1) > CHANGE_LEVEL
    labels, n_blobs = ndimage.label(changed, structure=np.ones((3, 3)))
    sizes = np.bincount(labels.ravel(), minlength=n_blobs + 1)
    cups = []
    for label in range(1, n_blobs + 1):
        if MIN_CUP_PIXELS * _scale(rgb) <= sizes[label] <= max_pixels:
            point = table_point(np.argwhere(labels == label).mean(axis=0) + 0.5, seen.intrinsic, seen.extrinsic,
                                CUP_PLANE_Z)
            if point is not None:
                cups.append((point, int(sizes[label])))
    return cups



def least_moves(old: np.ndarray, new: np.ndarray) -> tuple[int, ...]:
    """The match of each ``old`` point (n, 2) to a different ``new`` one (m >= n, 2) whose squared moves sum least:
    ``match[i]`` is the new point old point i went to."""
    if len(old) > len(new):
        raise ValueError(f"cannot match {len(old)} points to {len(new)} different ones")
    moves = np.linalg.norm(np.asarray(old)[:, None] - np.asarray(new)[None], axis=-1)
    return min(itertools.permutations(range(len(new)), len(old)),
               key=lambda m: sum(moves[i, j] ** 2 for i, j in enumerate(m)))



def swap_turn(old: np.ndarray, new: np.ndarray) -> float:
    """How far a pair of cups turned about its midpoint between two frames, in radians (-pi, pi], counter-clockwise
    seen from above positive: ``old`` and ``new`` (2, 2) are the pair's positions, cup by cup."""
    before, after = old[0] - old.mean(axis=0), new[0] - new.mean(axis=0)
    return float(np.angle(complex(*after) / complex(*before)))



def follow(cups: np.ndarray, seen: np.ndarray) -> np.ndarray | None:
    """Where each of three cups (3, 2) went among the positions ``seen`` (3, 2), by the law of MIKASA's shuffle: a
    swap turns two cups counter-clockwise (seen from above) about their midpoint, half a turn in all, while the
    third stands (MIKASA lifts all three alike meanwhile, which the cast onto the table shows as a shift toward the
    robot). Of the matches that obey it, the one whose squared moves sum least; None when none does (frames missed
    across a swap's end, or something else moving)."""
    best: tuple[float, np.ndarray] | None = None
    for match in itertools.permutations(range(len(seen))):
        new = seen[list(match)]
        moves = np.linalg.norm(new - cups, axis=1)
        cost = float((moves ** 2).sum())
        if moves.max() <= MAX_CUP_STEP and (best is None or cost < best[0]) and any(
                _one_swap(cups, new, idle) for idle in range(len(cups)) if moves[idle] <= IDLE_TOL):
            best = (cost, new)
    return None if best is None else best[1]



def _one_swap(cups: np.ndarray, new: np.ndarray, idle: int) -> bool:
    """Whether the two cups other than ``idle`` moved as a swapping pair does, once the lift's shift (the standing
    cup's) is taken off: not at all, or turning counter-clockwise about a fixed midpoint by less than ``MAX_TURN``
    (a half turn between two read frames cannot be told from none)."""
    pair = [i for i in range(len(cups)) if i != idle]
    moved = new[pair] - (new[idle] - cups[idle])
    if np.linalg.norm(moved - cups[pair], axis=1).max() <= REST_TOL:
        return True
    return bool(np.linalg.norm(moved.mean(axis=0) - cups[pair].mean(axis=0)) <= MID_TOL
                and 0 < swap_turn(cups[pair], moved) < MAX_TURN)


__all__ = ["BALL_MAX_RATIO", "BALL_MIN_LEVEL", "BALL_RADIUS", "CHANGE_LEVEL", "CUP_PLANE_Z", "CameraFrame", "IDLE_TOL", "MAX_CUP_AREA", "MAX_CUP_STEP", "MAX_TURN", "MID_TOL", "MIN_BALL_PIXELS", "MIN_CUP_PIXELS", "REST_TOL", "ball_mask", "ball_on_table", "cups_on_table", "follow", "least_moves", "swap_turn", "table_point"]
