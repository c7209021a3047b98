"""What the base camera shows of MIKASA-Robo-VLA's FindImposter cues: every object in view, read from pixels alone.

A FindImposter cue is a *set*: all objects but one stand at spread places on the table (a row for three, an
arc for more), unlike the Remember tasks' one cue at the table centre, so each object is seen from its own
angle and distance. ``objects_in_view`` finds them: pixels of a saturated colour (``cube_mask``) grouped by
hue family (red and maroon, lime, blue, yellow, magenta, cyan and teal, olive), one object per connected
group (a group of two touching objects, when fewer are in view than expected, is cut in two). Its colour is the
palette's top-face shade nearest the mean of its top face (its brightest pixels: a
top face renders the same shade anywhere on the table, the sides do not); its shape is scored against
per-shape prototypes of silhouette features (``shape_features``), sizes scaled by the object's distance from
the camera, measured per task on development seeds (``imposter_prototypes``, ``scripts/calibrate_imposter.py``).

``read_shown`` answers the set in view when it holds exactly as many objects as the cue shows, each a
different candidate: colours and shapes are given to objects jointly (``linear_sum_assignment``), so two
objects never take the same name.

Measured (``scripts/calibrate_imposter.py evaluate``: the cue frame of 60 episodes per task at seeds 5000-5059,
scored against the segmentation camera; the prototypes come from seeds 6000-6199): the frames whose set was read
exactly were FindImposterColor3 60, Color5 60, Color9 59 (one read as no set), Shape3 60, Shape5 55 (five
wrong), Shape9 45 (fifteen wrong), ShapeAndColor3x2 60, 3x3 56 (three no set, one wrong), 5x3 59 (one no set).
No colour task named an object wrong (Color9's misses are its one frame read as no set); shapes are what fails,
among nine most: of
Shape9's objects shown, named right were cube 46/50, sphere 49/52, cylinder 50/55, cross 52/55, torus 43/51, star
40/49, pyramid 50/53, t shape 51/58, crescent 53/57 (Shape5: cube 45/48, sphere 50/50, cylinder 44/45, cross
51/52, torus 45/45). Objects 6-20 pixels across seen from the camera's angle at each place do not separate nine
silhouettes as the centre's cue does (``shape_perception``); the wrist camera sees them larger and from above
but not the pyramid from the cube, and no better over all nine (a trial of similar features on segmented objects
of Shape9: 87% named right against the base camera's 85%).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from sb3_memret.tasks.mikasa.perception import BASE_RGB, COLOUR_NAMES, FACE_LEVELS, MIN_BLOB_PIXELS, cube_mask

# MIKASA's base camera (every cue task's): sapien_utils.look_at(eye, target), 128x128, a field of view of pi / 2.
BASE_EYE = np.array([0.3, 0.0, 0.6])
BASE_TARGET = np.array([-0.1, 0.0, 0.1])
FOCAL = 64.0  # pixels
REFERENCE_DISTANCE = 0.65  # metres: about the table centre's distance from the camera; sizes are scaled to it
OBJECT_HEIGHT = 0.02  # a cue object's middle above the table, where its pixels' rays are cut
TOP_FACE_TOL = 8  # a top-face pixel's brightest channel is within this of the object's brightest
MAX_TOP_DISTANCE = 30.0  # RGB: an object's top face is within 6 of its colour's anywhere, >= 60 from another's
TOP_COST_SCALE = 10.0  # a top face this far from a colour's costs as much as one spread of one shape feature
SPLIT_ITERATIONS = 10
FEATURE_FLOOR = 0.03  # the least spread a prototype's feature may have (a feature constant over calibration)
FEATURES = ("log_area", "height", "width", "fill", "holes", "top", "side", "shade_spread", "spread", "elongation",
            "mirror_lr", "mirror_ud")


def _rendered(colour: int, face: str) -> np.ndarray:
    return np.array([FACE_LEVELS[face][c] for c in BASE_RGB[colour]], dtype=np.float64)


TOP_SHADES = np.stack([_rendered(i, "top") for i in range(len(COLOUR_NAMES))])
# hue families: a colour's top shade over its brightest channel; red and maroon, cyan and teal share one
CHROMA = TOP_SHADES / TOP_SHADES.max(axis=1, keepdims=True)


def _camera_axes() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    forward = (BASE_TARGET - BASE_EYE) / np.linalg.norm(BASE_TARGET - BASE_EYE)
    left = np.cross([0.0, 0.0, 1.0], forward)
    left /= np.linalg.norm(left)
    return forward, left, np.cross(forward, left)


def view_distance(row: float, col: float) -> float:
    """Metres from the base camera to the point at ``OBJECT_HEIGHT`` above the table seen at pixel (row, col)."""
    forward, left, up = _camera_axes()
    ray = forward - (col + 0.5 - FOCAL) / FOCAL * left - (row + 0.5 - FOCAL) / FOCAL * up
    return float((OBJECT_HEIGHT - BASE_EYE[2]) / ray[2] * np.linalg.norm(ray))


def shape_features(rgb: np.ndarray, blob: np.ndarray) -> np.ndarray:
    """``FEATURES`` of one object's pixels: size (log pixel area, box height and width, all scaled to
    ``REFERENCE_DISTANCE``), the box's share it fills, its holes' share, its shading (shares on the flat top
    and side shades, spread of its brightest channel), its second moments, and its mirror symmetries."""
    cells = np.argwhere(blob)
    area = len(cells)
    (r0, c0), (r1, c1) = cells.min(axis=0), cells.max(axis=0) + 1
    scale = view_distance(*cells.mean(axis=0)) / REFERENCE_DISTANCE
    bright = np.asarray(rgb)[blob].max(axis=-1).astype(np.float64)
    top, side = FACE_LEVELS["top"][255], FACE_LEVELS["side"][255]
    y, x = (cells - cells.mean(axis=0)).T
    m20, m02, m11 = (np.mean(x * x), np.mean(y * y), np.mean(x * y))
    box = blob[r0:r1, c0:c1]
    return np.array([
        np.log(area) + 2 * np.log(scale), (r1 - r0) * scale, (c1 - c0) * scale, area / box.size,
        (ndimage.binary_fill_holes(box).sum() - area) / area,
        np.mean(np.abs(bright - top) <= TOP_FACE_TOL), np.mean(np.abs(bright - side) <= TOP_FACE_TOL),
        bright.std() / 50, (m20 + m02) / area, np.hypot(m20 - m02, 2 * m11) / area,
        np.sum(box & box[:, ::-1]) / area, np.sum(box & box[::-1]) / area,
    ])


@dataclass(frozen=True)
class SeenObject:
    """One object in view: its mask, the candidate colours' distances from its top face, and its colour family."""

    mask: np.ndarray
    top_distance: np.ndarray  # (n_colours,)
    family: int


def _seen(rgb: np.ndarray, blob: np.ndarray, family: int, n_colours: int, family_of: np.ndarray) -> SeenObject:
    values = rgb[blob].astype(np.float64)
    bright = values.max(axis=1)
    top = values[bright >= bright.max() - TOP_FACE_TOL].mean(axis=0)
    distance = np.linalg.norm(TOP_SHADES[:n_colours] - top, axis=1)
    distance[family_of != family] = np.inf
    return SeenObject(blob, distance, family)


def _scaled_area(blob: np.ndarray) -> float:
    """Pixels of ``blob`` scaled to ``REFERENCE_DISTANCE`` (a merged pair is about twice an object)."""
    cells = np.argwhere(blob)
    return len(cells) * (view_distance(*cells.mean(axis=0)) / REFERENCE_DISTANCE) ** 2


def split_in_two(blob: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``blob`` cut in two by 2-means on its pixels' places (started at its ends along its long axis); None when a
    half would be smaller than an object."""
    cells = np.argwhere(blob).astype(np.float64)
    centred = cells - cells.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    along = centred @ axis
    centres = np.stack([cells[along.argmin()], cells[along.argmax()]])
    for _ in range(SPLIT_ITERATIONS):
        side = ((cells[:, None] - centres[None]) ** 2).sum(-1).argmin(axis=1)
        if min(np.sum(side == 0), np.sum(side == 1)) < MIN_BLOB_PIXELS:
            return None
        centres = np.stack([cells[side == h].mean(axis=0) for h in (0, 1)])
    halves = []
    for h in (0, 1):
        half = np.zeros_like(blob)
        rows, cols = cells[side == h].astype(int).T
        half[rows, cols] = True
        halves.append(half)
    return halves[0], halves[1]


def objects_in_view(rgb: np.ndarray, n_colours: int, n_objects: int | None = None) -> list[SeenObject]:
    """Every object of a saturated colour in one base-camera frame (H, W, 3), by hue family and connected group.

    Objects that touch in the image make one group: with ``n_objects`` (how many the caller expects), while there
    are fewer groups the largest (by ``_scaled_area``) is cut in two (``split_in_two``)."""
    rgb = np.asarray(rgb)
    if rgb.shape[:2] != (128, 128) or rgb.shape[-1] != 3:
        raise ValueError(f"expected one 128x128 base-camera frame (H, W, 3), got shape {rgb.shape}")
    if not 1 <= n_colours <= len(COLOUR_NAMES):
        raise ValueError(f"n_colours must be in 1..{len(COLOUR_NAMES)}, got {n_colours}")
    mask = cube_mask(rgb)
    pixels = rgb[mask].astype(np.float64)
    chroma = pixels / np.maximum(pixels.max(axis=1, keepdims=True), 1.0)
    families, family_of = np.unique(CHROMA[:n_colours].round(1), axis=0, return_inverse=True)
    family_of = family_of.reshape(-1)
    family_map = np.full(mask.shape, -1)
    family_map[mask] = np.argmin(((chroma[:, None] - families[None]) ** 2).sum(-1), axis=1)
    groups = []
    for family in range(len(families)):
        labels, n = ndimage.label(family_map == family, structure=np.ones((3, 3)))
        groups += [(family, labels == label) for label in range(1, n + 1)
                   if np.sum(labels == label) >= MIN_BLOB_PIXELS]
    while n_objects is not None and 0 < len(groups) < n_objects:
        largest = max(range(len(groups)), key=lambda g: _scaled_area(groups[g][1]))
        family, blob = groups.pop(largest)
        halves = split_in_two(blob)
        if halves is None:
            groups.append((family, blob))
            break
        groups += [(family, half) for half in halves]
    return [_seen(rgb, blob, family, n_colours, family_of) for family, blob in groups]


def _assign(cost: np.ndarray) -> np.ndarray | None:
    """The candidate of each object (row), each candidate at most once, at least total cost; None if impossible."""
    if cost.shape[0] > cost.shape[1]:
        return None
    finite = np.where(np.isfinite(cost), cost, 1e9)
    rows, cols = linear_sum_assignment(finite)
    return None if np.any(finite[rows, cols] >= 1e9) else cols[np.argsort(rows)]


def shape_costs(rgb: np.ndarray, objects: Sequence[SeenObject], prototypes: Mapping[str, tuple[Sequence[float],
                Sequence[float]]], shapes: Sequence[str]) -> np.ndarray:
    """Each object's squared scaled distance (rows) to each of ``shapes``' prototypes (columns)."""
    means = np.array([prototypes[s][0] for s in shapes])
    spreads = np.maximum(np.array([prototypes[s][1] for s in shapes]), FEATURE_FLOOR)
    features = np.array([shape_features(rgb, o.mask) for o in objects]).reshape(len(objects), len(FEATURES))
    return (((features[:, None] - means[None]) / spreads[None]) ** 2).sum(-1)


def assign_shown(rgb: np.ndarray, candidates: Sequence[tuple[str | None, str | None]], n_shown: int,
                 prototypes: Mapping[str, tuple[Sequence[float], Sequence[float]]] | None = None
                 ) -> list[tuple[SeenObject, int]] | None:
    """Each object in view with the candidate (index) it is read as, when exactly ``n_shown`` objects are in view
    and each reads as a different candidate; else None.

    A candidate is (colour, shape): its colour one of ``COLOUR_NAMES`` or None (the task's objects share one, blue),
    its shape a key of ``prototypes`` or None (they share one). Objects take candidates jointly at the least total
    cost: a candidate whose colour's top face lies farther than ``MAX_TOP_DISTANCE`` from an object's is out for it
    (nearer, the distance costs a little); a shape costs the object's scaled distance to the shape's prototype.
    """
    blue = COLOUR_NAMES.index("blue")
    colours = [blue if colour is None else COLOUR_NAMES.index(colour) for colour, _ in candidates]
    objects = objects_in_view(rgb, max(colours) + 1, n_shown)
    if len(objects) != n_shown:
        return None
    top = np.array([[o.top_distance[c] for c in colours] for o in objects]).reshape(len(objects), len(candidates))
    cost = np.where(top <= MAX_TOP_DISTANCE, (top / TOP_COST_SCALE) ** 2, np.inf)
    shapes = [shape for _, shape in candidates]
    if any(shape is not None for shape in shapes):
        if prototypes is None or any(shape is None for shape in shapes):
            raise ValueError("candidates that name shapes need every candidate's shape and the task's shape prototypes")
        cost = cost + shape_costs(rgb, objects, prototypes, shapes)
    chosen = _assign(cost)
    return None if chosen is None else [(o, int(j)) for o, j in zip(objects, chosen)]


def read_shown(rgb: np.ndarray, candidates: Sequence[tuple[str | None, str | None]], n_shown: int,
               prototypes: Mapping[str, tuple[Sequence[float], Sequence[float]]] | None = None
               ) -> tuple[int, ...] | None:
    """The candidates in view (their indices, ascending) when exactly ``n_shown`` objects are, each read as a different
    candidate (``assign_shown``); else None."""
    assigned = assign_shown(rgb, candidates, n_shown, prototypes)
    return None if assigned is None else tuple(sorted(j for _, j in assigned))


__all__ = ["FEATURES", "SeenObject", "assign_shown", "objects_in_view", "read_shown", "shape_costs", "shape_features",
           "split_in_two", "view_distance"]
