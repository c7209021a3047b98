"""What the base camera shows of MIKASA-Robo-VLA's FindImposter cues: every object in view, read from pixels alone.

A FindImposter cue is a *set*: all objects but one stand at spread places on the table (a row for three, an
arc for more), unlike the Remember tasks' one cue at the table centre, so each object is seen from its own
angle and distance. ``objects_in_view`` finds them: pixels of a saturated colour (``cube_mask``) grouped by
hue family (red and maroon, lime, blue, yellow, magenta, cyan and teal, olive), one object per connected
group (a group of two touching objects, when fewer are in view than expected, is cut in two). Its colour is the
palette's top-face shade nearest the mean of its top face (its brightest pixels: a
top face renders the same shade anywhere on the table, the sides do not). Its shape is read by matching: every
shape stands in one fixed orientation at one of a few places (jittered about a centimetre), so an object looks like
the same shape seen at the same place before. ``ShapeExemplars`` holds, per task, the objects of the cue frames of 200
development episodes (seeds 6000-6199, named by the segmentation camera: ``scripts/calibrate_imposter.py
calibrate``), each as its place in the image and its shading around it (``object_crop``); an object's cost as a
shape is its crop's least distance to that shape's exemplars seen at its place.

``read_shown`` answers the set in view when it holds exactly as many objects as the cue shows, each a
different candidate: colours and shapes are given to objects jointly (``linear_sum_assignment``), so two
objects never take the same name.

Measured (``scripts/calibrate_imposter.py evaluate``: the cue frame of 60 episodes per task at seeds 5000-5059,
scored against the segmentation camera): the frames whose set was read exactly were FindImposterColor3 60, Color5
60, Color9 59 (one read as no set), Shape3 60, Shape5 60, Shape9 60, ShapeAndColor3x2 60, 3x3 57 (three read as no
set), 5x3 59 (one no set). No frame was read wrong; a frame read as no set has two objects merged in view (every cue
frame of an episode is the same, so its writer writes no fact). Before, shapes were scored against per-shape means of twelve silhouette features
scaled by distance: Shape5 55 and Shape9 45 frames read exactly, the rest wrong (nine shapes 6-20 pixels across,
seen from a different angle at each place, do not separate by size and moments alone).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from sb3_memret.tasks.mikasa.core.perception import BASE_RGB, COLOUR_NAMES, FACE_LEVELS, MIN_BLOB_PIXELS, cube_mask

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
CROP_HALF = 10  # pixels each side of an object's centre that its crop keeps: the largest cue object is 20 across
CROP_LEVELS = 255  # a crop's shades are stored as integers 0..CROP_LEVELS
CROP_SHIFTS = (-1, 0, 1)  # pixels a crop may sit off an exemplar's, down and across (centres round to a pixel)
NEAR_PLACE = 4.0  # pixels: an exemplar whose centre lies this close to an object's was seen at its place
NEAREST_PLACES = 5  # a shape with no exemplar that near: this many of its exemplars nearest the object's place
MATCH_SCALE = 3.0  # a crop distance (summed shade differences) this large costs as much as 1 (costs are squared)
EXEMPLARS_DIR = Path(__file__).resolve().parents[1] / "assets" / "imposter_exemplars"


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


def object_crop(rgb: np.ndarray, blob: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre (row, col), crop): the object's shading in a window of ``2 * CROP_HALF + 1`` pixels around its centre,
    each of its pixels' brightest channel over the object's brightest (so any colour shades alike), 0 off it."""
    cells = np.argwhere(blob)
    centre = cells.mean(axis=0)
    row, col = np.round(centre).astype(int)
    bright = np.asarray(rgb).max(axis=-1).astype(np.float32)
    shading = np.pad(np.where(blob, bright / bright[blob].max(), 0.0), CROP_HALF)
    return centre, shading[row:row + 2 * CROP_HALF + 1, col:col + 2 * CROP_HALF + 1]


@dataclass(frozen=True)
class ShapeExemplars:
    """A task's objects as the base camera saw them in calibration cue frames: where each stood (its centre in the
    image), its crop (``object_crop``) and its shape's name.

    Every shape stands in one fixed orientation and at one of a few places (MIKASA's spread places, jittered about
    a centimetre, a pixel or two), so an object looks like the exemplars of its shape seen at its place."""

    centres: np.ndarray  # (n, 2) float32
    crops: np.ndarray  # (n, 2 * CROP_HALF + 1, 2 * CROP_HALF + 1) float32 in [0, 1]
    shapes: np.ndarray  # (n,) str

    def __post_init__(self) -> None:
        n, side = len(self.shapes), 2 * CROP_HALF + 1
        if self.centres.shape != (n, 2) or self.crops.shape != (n, side, side) or n == 0:
            raise ValueError(f"exemplars need as many centres (n, 2) and crops (n, {side}, {side}) as shapes (n > 0); "
                             f"got {self.centres.shape}, {self.crops.shape} and {n}")

    @classmethod
    def load(cls, path: Path) -> "ShapeExemplars":
        """Exemplars saved by ``save``; a missing file is a FileNotFoundError naming it and how it is made."""
        if not Path(path).is_file():
            raise FileNotFoundError(f"no shape exemplars at {path}: `python scripts/calibrate_imposter.py calibrate` "
                                    "writes them")
        with np.load(path) as data:
            return cls(data["centres"], data["crops"].astype(np.float32) / CROP_LEVELS, data["shapes"])

    def save(self, path: Path) -> None:
        """Written compressed, each crop's shades in ``CROP_LEVELS`` integer levels."""
        crops = np.round(np.clip(self.crops, 0.0, 1.0) * CROP_LEVELS).astype(np.uint8)
        np.savez_compressed(path, centres=self.centres.astype(np.float32), crops=crops, shapes=self.shapes)

    def costs(self, rgb: np.ndarray, objects: Sequence["SeenObject"], shapes: Sequence[str]) -> np.ndarray:
        """Each object's cost (rows) as each of ``shapes`` (columns): (its crop's least distance to the shape's
        exemplars seen at its place, over ``CROP_SHIFTS``, / ``MATCH_SCALE``) squared."""
        unknown = sorted(set(shapes) - set(self.shapes.tolist()))
        if unknown:
            raise ValueError(f"no exemplars of shapes {unknown}; these exemplars hold {sorted(set(self.shapes))}")
        cost = np.zeros((len(objects), len(shapes)))
        for i, seen in enumerate(objects):
            centre, crop = object_crop(rgb, seen.mask)
            shifted = np.stack([np.roll(crop, (dr, dc), axis=(0, 1)) for dr in CROP_SHIFTS for dc in CROP_SHIFTS])
            place = np.linalg.norm(self.centres - centre, axis=1)
            for j, shape in enumerate(shapes):
                own = np.flatnonzero(self.shapes == shape)
                near = own[place[own] <= NEAR_PLACE]
                if len(near) == 0:
                    near = own[np.argsort(place[own])[:NEAREST_PLACES]]
                distance = np.abs(self.crops[near][:, None] - shifted[None]).sum(axis=(2, 3)).min()
                cost[i, j] = (distance / MATCH_SCALE) ** 2
        return cost


@lru_cache(maxsize=None)
def task_exemplars(env_id: str) -> ShapeExemplars:
    """The shipped exemplars of a FindImposter task whose objects differ in shape (``EXEMPLARS_DIR/<env id>.npz``)."""
    return ShapeExemplars.load(EXEMPLARS_DIR / f"{env_id}.npz")


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


def objects_in_view(rgb: np.ndarray, n_colours: int, n_objects: int | None = None,
                    per_colour: Sequence[int] | None = None) -> list[SeenObject]:
    """Every object of a saturated colour in one base-camera frame (H, W, 3), by hue family and connected group.

    Objects that touch in the image make one group: with ``n_objects`` (how many the caller expects), while there
    are fewer groups the largest (by ``_scaled_area``) is cut in two (``split_in_two``). With ``per_colour`` (how
    many of each of the ``n_colours`` the caller expects), only a family with fewer groups than that has its largest
    cut: a near object, large in the picture, is not cut while two far ones of another colour stay merged."""
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
    if per_colour is not None and len(per_colour) != n_colours:
        raise ValueError(f"per_colour needs one count for each of the {n_colours} colours, got {list(per_colour)}")
    wanted = None if per_colour is None else np.bincount(family_of, weights=per_colour, minlength=len(families))
    while n_objects is not None and 0 < len(groups) < n_objects:
        short = [g for g in range(len(groups))
                 if wanted is None or sum(f == groups[g][0] for f, _ in groups) < wanted[groups[g][0]]]
        if not short:
            break
        largest = max(short, key=lambda g: _scaled_area(groups[g][1]))
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


def assign_shown(rgb: np.ndarray, candidates: Sequence[tuple[str | None, str | None]], n_shown: int,
                 exemplars: ShapeExemplars | None = None,
                 by_colour: bool = False) -> list[tuple[SeenObject, int]] | None:
    """Each object in view with the candidate (index) it is read as, when exactly ``n_shown`` objects are in view
    and each reads as a different candidate; else None.

    A candidate is (colour, shape): its colour one of ``COLOUR_NAMES`` or None (the task's objects share one, blue),
    its shape one of ``exemplars``' or None (they share one). Objects take candidates jointly at the least total
    cost: a candidate whose colour's top face lies farther than ``MAX_TOP_DISTANCE`` from an object's is out for it
    (nearer, the distance costs a little); a shape costs what ``ShapeExemplars.costs`` says. ``by_colour``: every
    candidate is in view, so touching objects are cut apart colour by colour (``objects_in_view``'s ``per_colour``).
    """
    blue = COLOUR_NAMES.index("blue")
    colours = [blue if colour is None else COLOUR_NAMES.index(colour) for colour, _ in candidates]
    per_colour = np.bincount(colours, minlength=max(colours) + 1) if by_colour else None
    objects = objects_in_view(rgb, max(colours) + 1, n_shown, per_colour)
    if len(objects) != n_shown:
        return None
    top = np.array([[o.top_distance[c] for c in colours] for o in objects]).reshape(len(objects), len(candidates))
    cost = np.where(top <= MAX_TOP_DISTANCE, (top / TOP_COST_SCALE) ** 2, np.inf)
    shapes = [shape for _, shape in candidates]
    if any(shape is not None for shape in shapes):
        if exemplars is None or any(shape is None for shape in shapes):
            raise ValueError("candidates that name shapes need every candidate's shape and the task's shape exemplars")
        cost = cost + exemplars.costs(rgb, objects, shapes)
    chosen = _assign(cost)
    return None if chosen is None else [(o, int(j)) for o, j in zip(objects, chosen)]


def read_shown(rgb: np.ndarray, candidates: Sequence[tuple[str | None, str | None]], n_shown: int,
               exemplars: ShapeExemplars | None = None) -> tuple[int, ...] | None:
    """The candidates in view (their indices, ascending) when exactly ``n_shown`` objects are, each read as a different
    candidate (``assign_shown``); else None."""
    assigned = assign_shown(rgb, candidates, n_shown, exemplars)
    return None if assigned is None else tuple(sorted(j for _, j in assigned))


__all__ = ["ShapeExemplars", "SeenObject", "assign_shown", "object_crop", "objects_in_view", "read_shown", "task_exemplars",
           "split_in_two", "view_distance"]
