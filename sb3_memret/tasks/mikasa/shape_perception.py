"""What a camera sees of MIKASA-Robo-VLA's RememberShape3 task, and what a frozen controller may read.

``read_cue_shape`` reads the cue's shape from pixels alone; ``ShapeControllerObservation`` strips the
env's observation down to what a controller with a camera and a shape detector would see.

Calibration (SAPIEN 3.0.3 rasteriser, lavapipe, the 128x128 ``base_camera``; MIKASA's evaluation
seeds 4242424242 + i). Every shape is the same blue (0, 0, 255), 4 cm across, and the cue stands
at the table centre in a fixed orientation with the arm parked (actions are no-ops in the cue
phase), so a cue frame is the same, pixel for pixel, in every episode of a shape. The blue pixels
(``cube_mask``: min channel <= 20, max >= 80; no table, floor or robot pixel passes) of the three
cues, rows x columns of their bounding box, the share of it they fill, and the share of them on one
of the two flat face shades (blue 231 top, 148 camera-facing side, +-6):

=========  ======  =====  =====  ====
shape      pixels  box    fill   flat
=========  ======  =====  =====  ====
cube       24      6x4    1.00   1.00
cylinder   18      5x4    0.90   1.00
sphere     14      4x4    0.88   0.21
=========  ======  =====  =====  ====

The sphere is smooth-shaded (blue 153-238 over its 14 pixels); the cube's two faces and the
cylinder's top and (at this resolution) side are flat. Area and aspect alone separate the three,
shading separates the sphere from the others a second way; ``read_cue_shape`` takes the nearest of
the measured prototypes and refuses a blob that is near none (a gripper finger over a shape, a
shape cut by the frame). Calibrated for the first three shapes of MIKASA's SHAPE_MAPPING
(RememberShape3) only: RememberShape5/9's cross, torus, star, ... are not.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from sb3_memret.tasks.mikasa.perception import FACE_LEVELS, REFERENCE_SIZE, DetectorObservation, cue_blob

# MIKASA's RememberShapeVLABaseEnv.SHAPE_MAPPING, in order: index i is actor ``shape_actors[i]``.
SHAPE_NAMES: tuple[str, ...] = ("cube", "sphere", "cylinder", "cross", "torus", "star", "pyramide", "t_shape",
                                "crescent")
CALIBRATED_SHAPES = 3  # prototypes exist for cube, sphere and cylinder (RememberShape3)
FLAT_LEVELS = (FACE_LEVELS["top"][255], FACE_LEVELS["side"][255])  # blue of a flat top / side face: 231, 148
FLAT_TOL = 6
# Each cue's silhouette at 128x128 (measured, see the table above): pixels, rows / columns of its
# bounding box, the box's share it fills, and its share of flat-shaded pixels.
PROTOTYPES: dict[str, tuple[float, float, float, float]] = {
    "cube": (24.0, 1.50, 1.000, 1.00),
    "sphere": (14.0, 1.00, 0.875, 0.21),
    "cylinder": (18.0, 1.25, 0.900, 1.00),
}
# How far a feature may stray, per prototype distance unit: pixels in log-ratio, aspect, fill, flat share.
FEATURE_SCALE = np.array([0.12, 0.15, 0.08, 0.25])
MAX_DISTANCE = 1.0  # a blob farther than this from every prototype is not read (the prototypes are >= 3.1 apart)


def shape_features(rgb: np.ndarray, blob: np.ndarray) -> np.ndarray:
    """(pixels at 128x128, rows / columns of the bounding box, fill of the box, share of flat-shaded pixels)."""
    scale = np.array(blob.shape) / REFERENCE_SIZE
    cells = np.argwhere(blob)
    rows, cols = cells.max(axis=0) - cells.min(axis=0) + 1
    area = len(cells)
    brightest = np.asarray(rgb)[blob].max(axis=-1).astype(np.float32)
    flat = np.min([np.abs(brightest - level) for level in FLAT_LEVELS], axis=0) <= FLAT_TOL
    return np.array([area / scale.prod(), rows / cols, area / (rows * cols), flat.mean()])


def shape_distances(features: np.ndarray, n_shapes: int) -> np.ndarray:
    """The scaled distance of ``features`` to each of the first ``n_shapes`` shapes' prototypes."""
    protos = np.array([PROTOTYPES[name] for name in SHAPE_NAMES[:n_shapes]])
    delta = np.column_stack([np.log(features[0] / protos[:, 0]), features[1:] - protos[:, 1:]]) / FEATURE_SCALE
    return np.linalg.norm(delta, axis=1)


def read_cue_shape(rgb: np.ndarray, n_shapes: int = 3) -> str | None:
    """The shape of the one object at the table centre, or None when no object or several are in view.

    Reads one base-camera frame (H, W, 3) uint8 only: the cue phase is the only phase with exactly
    one object in sight, at the table centre. Its silhouette and shading go to the nearest of the
    first ``n_shapes`` shapes' prototypes; a blob near none of them reads as None.
    """
    if not 1 <= n_shapes <= CALIBRATED_SHAPES:
        raise ValueError(f"read_cue_shape is calibrated for the first {CALIBRATED_SHAPES} shapes "
                         f"{SHAPE_NAMES[:CALIBRATED_SHAPES]} (RememberShape3), got n_shapes={n_shapes}")
    blob = cue_blob(rgb)
    if blob is None:
        return None
    distances = shape_distances(shape_features(rgb, blob), n_shapes)
    best = int(distances.argmin())
    return SHAPE_NAMES[best] if distances[best] <= MAX_DISTANCE else None


def _shape_actors(base: Any) -> list[Any]:
    return [base.shape_actors[i] for i in sorted(base.shape_actors)]


class ShapeControllerObservation(DetectorObservation):
    """A RememberShape observation cut to a controller's view: ``extra/shape_positions`` (B, n_shapes, 3) and
    ``extra/shape_visible`` (B, n_shapes) by SHAPE_MAPPING index, as a shape detector would report them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, _shape_actors, "shape")
        self.n_shapes = self.n_objects


__all__ = ["CALIBRATED_SHAPES", "DetectorObservation", "PROTOTYPES", "SHAPE_NAMES", "ShapeControllerObservation",
           "read_cue_shape", "shape_distances", "shape_features"]
