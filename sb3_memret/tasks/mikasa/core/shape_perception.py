"""What a camera sees of MIKASA-Robo-VLA's RememberShape tasks, and what a frozen controller may read.

``read_cue_shape`` reads the cue's shape from pixels alone; ``ShapeControllerObservation`` strips the
env's observation down to what a controller with a camera and a shape detector would see.

Calibration (SAPIEN 3.0.3 rasteriser, lavapipe, the 128x128 ``base_camera``). Every shape is 4-6 cm
across and the cue stands at the table centre in a fixed orientation with the arm parked (actions are
no-ops in the cue phase), so a cue frame is the same, pixel for pixel, in every episode of a shape: its
silhouette, each pixel marked by the shade of its brightest channel (``#`` the flat top-face shade
231, ``+`` the flat camera-facing-side shade 148, ``o`` any other shade, ``.`` not the object), is
one of ``SILHOUETTES``. Measured at seeds 5000-5059 of RememberShape9 (all nine shapes) and of
RememberShapeAndColor5x3 (five of them in red, lime and blue: the same silhouettes in every colour):

=========  ======  ====  ==================================================
shape      pixels  box   silhouette, top row first
=========  ======  ====  ==================================================
cube       24      6x4   ``####`` x4, ``++++`` x2
sphere     14      4x4   ``o##o o#oo oooo .++.`` (smooth-shaded)
cylinder   18      5x4   ``.##. #### #### +##+ ++++``
cross      20      6x6   a plus sign two pixels thick
torus      24      5x6   a ring around a two-pixel hole
star       22      5x6   ``.####. .+##+. ###### ++##++ ..##..``
pyramid    20      5x4   a square, its two sloping faces in side shade
t shape    14      5x4   ``..## #### #### ..o# ..++``
crescent   15      5x4   ``###. #### ..## .### ###.``
=========  ======  ====  ==================================================

``silhouette_match`` scores a blob against a silhouette: the share of cells, over those either marks
as object, on which both agree (half a point where both are object but shaded differently), at the
best of the nine one-pixel shifts. Every silhouette scores 1.0 against itself and at most 0.75 against
another (cube against pyramid and cylinder), so ``read_cue_shape`` takes the best of the candidates
when it scores at least ``MIN_MATCH`` (0.875) and refuses a blob that matches none (a gripper finger
over a shape, a shape cut by the frame). Over the cue frames of 60 episodes each of RememberShape3,
RememberShape5 and RememberShape9 at seeds 5000-5059, every shape read right on every cue frame and no
frame of the delay or choice phases read as a shape (``tests/test_mikasa_shape.py``).
"""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym
import numpy as np

from sb3_memret.tasks.mikasa.core.perception import FACE_LEVELS, DetectorObservation, cue_blob

# MIKASA's RememberShapeVLABaseEnv.SHAPE_MAPPING, in order: index i is actor ``shape_actors[i]``. Worded as prompts
# word them (lowercase words: MIKASA's "pyramide" and "t_shape" are "pyramid" and "t shape").
SHAPE_NAMES: tuple[str, ...] = ("cube", "sphere", "cylinder", "cross", "torus", "star", "pyramid", "t shape",
                                "crescent")
# Each shape's cue at the table centre in the 128x128 base camera (measured, see the table above).
SILHOUETTES: dict[str, tuple[str, ...]] = {
    "cube": ("####", "####", "####", "####", "++++", "++++"),
    "sphere": ("o##o", "o#oo", "oooo", ".++."),
    "cylinder": (".##.", "####", "####", "+##+", "++++"),
    "cross": ("..##..", "..##..", "######", "######", "..##..", "..##.."),
    "torus": (".####.", "##++##", "##..##", "+####+", ".+##+."),
    "star": (".####.", ".+##+.", "######", "++##++", "..##.."),
    "pyramid": ("####", "####", "#++#", "#++#", "++++"),
    "t shape": ("..##", "####", "####", "..o#", "..++"),
    "crescent": ("###.", "####", "..##", ".###", "###."),
}
SHADES = {".": 0, "#": 1, "+": 2, "o": 3}
TOP_SHADE, SIDE_SHADE = FACE_LEVELS["top"][255], FACE_LEVELS["side"][255]  # 231, 148 in any of R, G, B
SHADE_TOL = 8
MIN_MATCH = 0.875  # a blob matching no silhouette this well is not read (two silhouettes match at most 0.75)
SHIFTS = (-1, 0, 1)  # pixels a blob may sit off a silhouette's alignment, down and across


def check_shapes(shapes: Sequence[str] | int) -> tuple[str, ...]:
    """``shapes`` as a tuple of names, each one of ``SHAPE_NAMES`` (a number n: the first n of them); else a
    ValueError naming the unknown ones."""
    if isinstance(shapes, int):
        if not 1 <= shapes <= len(SHAPE_NAMES):
            raise ValueError(f"a number of shapes must be in 1..{len(SHAPE_NAMES)}, got {shapes}")
        return SHAPE_NAMES[:shapes]
    shapes = tuple(shapes)
    unknown = [s for s in shapes if s not in SILHOUETTES]
    if not shapes or unknown:
        raise ValueError(f"unknown shapes {unknown} (or none given); expected some of {list(SHAPE_NAMES)}")
    return shapes


def silhouette(rgb: np.ndarray, blob: np.ndarray) -> np.ndarray:
    """The blob's bounding box as shade codes (``SHADES``): top face, side face, other shade, not the blob."""
    cells = np.argwhere(blob)
    (r0, c0), (r1, c1) = cells.min(axis=0), cells.max(axis=0) + 1
    value = np.asarray(rgb)[r0:r1, c0:c1].max(axis=-1).astype(np.int16)
    codes = np.full(value.shape, SHADES["o"], dtype=np.int8)
    codes[np.abs(value - TOP_SHADE) <= SHADE_TOL] = SHADES["#"]
    codes[np.abs(value - SIDE_SHADE) <= SHADE_TOL] = SHADES["+"]
    codes[~blob[r0:r1, c0:c1]] = SHADES["."]
    return codes


def _codes(rows: Sequence[str]) -> np.ndarray:
    return np.array([[SHADES[c] for c in row] for row in rows], dtype=np.int8)


def silhouette_match(grid: np.ndarray, rows: Sequence[str]) -> float:
    """How well shade codes ``grid`` match the silhouette ``rows``: agreeing cells (0.5 for object cells
    shaded differently) over the cells either marks as object, at the best one-pixel shift."""
    template = _codes(rows)
    pad = max(abs(s) for s in SHIFTS)
    height = max(grid.shape[0], template.shape[0]) + 2 * pad
    width = max(grid.shape[1], template.shape[1]) + 2 * pad
    seen = np.zeros((height, width), dtype=np.int8)
    seen[pad:pad + grid.shape[0], pad:pad + grid.shape[1]] = grid
    best = 0.0
    for dr in SHIFTS:
        for dc in SHIFTS:
            shape = np.zeros_like(seen)
            shape[pad + dr:pad + dr + template.shape[0], pad + dc:pad + dc + template.shape[1]] = template
            both = (seen > 0) & (shape > 0)
            agree = np.sum(both & (seen == shape)) + 0.5 * np.sum(both & (seen != shape))
            best = max(best, float(agree / np.sum((seen > 0) | (shape > 0))))
    return best


def read_cue_shape(rgb: np.ndarray, shapes: Sequence[str] | int = 3) -> str | None:
    """The shape, one of ``shapes`` (names, or n for the first n of ``SHAPE_NAMES``), of the one object at the
    table centre; None when no object or several are in view, or when its silhouette matches none of theirs.

    Reads one base-camera frame (H, W, 3) uint8 only, at 128x128 (the silhouettes' resolution): the cue
    phase is the only phase with exactly one object in sight, at the table centre.
    """
    shapes = check_shapes(shapes)
    rgb = np.asarray(rgb)
    if rgb.shape[:2] != (128, 128):
        raise ValueError(f"the silhouettes are measured at 128x128 (MIKASA's base camera), got a frame of {rgb.shape}")
    blob = cue_blob(rgb)
    if blob is None:
        return None
    grid = silhouette(rgb, blob)
    scores = [silhouette_match(grid, SILHOUETTES[s]) for s in shapes]
    best = int(np.argmax(scores))
    return shapes[best] if scores[best] >= MIN_MATCH else None


def _shape_actors(base: Any) -> list[Any]:
    return [base.shape_actors[i] for i in sorted(base.shape_actors)]


class ShapeControllerObservation(DetectorObservation):
    """A RememberShape observation cut to a controller's view: ``extra/shape_positions`` (B, n_shapes, 3) and
    ``extra/shape_visible`` (B, n_shapes) by SHAPE_MAPPING index, as a shape detector would report them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, _shape_actors, "shape")
        self.n_shapes = self.n_objects


__all__ = ["DetectorObservation", "MIN_MATCH", "SHAPE_NAMES", "SILHOUETTES", "ShapeControllerObservation",
           "check_shapes", "read_cue_shape", "silhouette", "silhouette_match"]
