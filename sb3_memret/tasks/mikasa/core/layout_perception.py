"""Where each coloured cube stands on the table, read from one base-camera frame and the camera's calibration.

Each blob of cube pixels (``perception.cube_mask``) is named by the colour most of its pixels are nearest to (the
rendered face shades, as ``read_cue_colour`` names the cue), and its pixels' mean is cast along the camera ray onto
the plane ``z = plane_z``. Measured on SeqOfColors3 (4 cm cubes, the 128x128 ``base_camera``, the first frame with
the cubes out, development seeds 5000-5009): all nine cubes read in every frame, each (x, y) within 0.55 cm of the
simulator's at ``plane_z = 0.02`` (up to 1 cm at 0.03: the seen pixels' mean sits near the cube's centre height, its
top face and camera-facing side both showing), and the button placed from their mean within 0.1 cm.
"""

from __future__ import annotations

from typing import Any, Callable, Mapping

import numpy as np
from scipy import ndimage

from sb3_memret.controllers.base import as_numpy
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES, MIN_BLOB_PIXELS, REFERENCE_SIZE, _palette, cube_mask

LAYOUT_PLANE_Z = 0.02  # the height a cube's seen pixels are cast onto (its centre's, for 4 cm cubes)
# a blob's colour needs this share of its pixels' votes: off the table centre a cube's faces shade differently from
# the cue's calibrated shades (a maroon cube on the arc: 19 of 24 pixels maroon, 5 red), so less than the cue's 0.8
LAYOUT_VOTE_SHARE = 0.6
# a blob of touching cubes is split by colour into parts of at least this many pixels at 128x128 (a cube shows about
# 24; a face shaded toward another colour, up to 5)
SPLIT_MIN_PIXELS = 8


def rgb_frame(rgb: Any) -> np.ndarray:
    """One (H, W, 3) camera frame as signed integers (so channel differences do not wrap); a ValueError otherwise."""
    frame = np.asarray(as_numpy(rgb)).astype(np.int16)
    if frame.ndim != 3 or frame.shape[-1] != 3:
        raise ValueError(f"expected one (H, W, 3) frame, got shape {frame.shape}")
    return frame


def cast_mask(mask: np.ndarray, plane_z: float, least: float) -> np.ndarray | None:
    """Where the mean pixel of ``mask`` (H, W) meets the plane ``z = plane_z``, through the base camera's shipped
    calibration; None with fewer than ``least`` pixels (counted at 128x128)."""
    if mask.sum() < least * np.prod(np.array(mask.shape) / REFERENCE_SIZE):
        return None
    point = table_points((np.argwhere(mask).mean(axis=0) + 0.5)[None], BASE_CAMERA_INTRINSIC,
                         BASE_CAMERA_EXTRINSIC, plane_z)[0]
    return point if np.isfinite(point).all() else None


def table_points(pixels: np.ndarray, intrinsic: np.ndarray, extrinsic: np.ndarray, plane_z: float) -> np.ndarray:
    """World (x, y) where the camera rays through ``pixels`` ((N, 2) row, col, pixel centres at +0.5) meet the plane
    ``z = plane_z``; ``intrinsic`` is OpenCV's 3x3, ``extrinsic`` world-to-camera 3x4. NaN for a ray parallel to it."""
    pixels = np.atleast_2d(np.asarray(pixels, dtype=np.float64))
    homogeneous = np.column_stack([pixels[:, 1], pixels[:, 0], np.ones(len(pixels))])
    rotation, translation = np.asarray(extrinsic, dtype=np.float64)[:, :3], np.asarray(extrinsic)[:, 3]
    rays = (rotation.T @ np.linalg.inv(np.asarray(intrinsic, dtype=np.float64)) @ homogeneous.T).T
    origin = -rotation.T @ translation
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(np.abs(rays[:, 2]) > 1e-9, (plane_z - origin[2]) / rays[:, 2], np.nan)
    return (origin[None] + scale[:, None] * rays)[:, :2]


def name_blobs(rgb: np.ndarray, n_colours: int) -> dict[str, np.ndarray]:
    """Colour -> (row, col) pixel centre of every cube one frame (H, W, 3) shows, among the first ``n_colours``
    colours. A blob where more than one colour covers ``SPLIT_MIN_PIXELS`` is split into each colour's connected
    parts (cubes touching in the image); a blob of one colour with a few pixels of others (a face shaded off) is
    that colour's where it holds ``LAYOUT_VOTE_SHARE`` of the votes; a colour seen as two blobs is left out."""
    if not 1 <= n_colours <= len(COLOUR_NAMES):
        raise ValueError(f"n_colours must be in 1..{len(COLOUR_NAMES)}, got {n_colours}")
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"expected one (H, W, 3) frame, got shape {rgb.shape}")
    labels, n_blobs = ndimage.label(cube_mask(rgb), structure=np.ones((3, 3)))
    scale = np.prod(np.array(rgb.shape[:2]) / REFERENCE_SIZE)
    min_pixels, split_pixels = MIN_BLOB_PIXELS * scale, SPLIT_MIN_PIXELS * scale
    shades, owner = _palette(n_colours)
    found: dict[str, list[np.ndarray]] = {}
    for blob in range(1, n_blobs + 1):
        where = np.argwhere(labels == blob)
        if len(where) < min_pixels:
            continue
        pixels = rgb[labels == blob].astype(np.float32)
        owned = owner[np.argmin(((pixels[:, None] - shades[None]) ** 2).sum(-1), axis=1)]
        votes = np.bincount(owned, minlength=n_colours)
        cubes = np.flatnonzero(votes >= split_pixels)
        if len(cubes) > 1:
            # cubes of different colours touching in the image (nine on an arc, seen from across the table): each
            # colour's own connected parts, where large enough to be a cube's
            owners = np.full(labels.shape, -1)
            owners[labels == blob] = owned
            for colour in cubes:
                parts, n_parts = ndimage.label(owners == colour, structure=np.ones((3, 3)))
                for part in range(1, n_parts + 1):
                    part_pixels = np.argwhere(parts == part)
                    if len(part_pixels) >= split_pixels:
                        found.setdefault(COLOUR_NAMES[colour], []).append(part_pixels.mean(axis=0) + 0.5)
            continue
        best = int(votes.argmax())
        if votes[best] >= LAYOUT_VOTE_SHARE * votes.sum():
            found.setdefault(COLOUR_NAMES[best], []).append(where.mean(axis=0) + 0.5)
    return {colour: centres[0] for colour, centres in found.items() if len(centres) == 1}


def read_cube_layout(rgb: np.ndarray, intrinsic: np.ndarray, extrinsic: np.ndarray, n_colours: int,
                     plane_z: float = LAYOUT_PLANE_Z) -> dict[str, np.ndarray]:
    """Colour -> table (x, y) of every cube one base-camera frame (H, W, 3) shows (``name_blobs``), cast with the
    camera's calibration onto the plane ``z = plane_z``."""
    named = name_blobs(rgb, n_colours)
    if not named:
        return {}
    points = table_points(np.array(list(named.values())), intrinsic, extrinsic, plane_z)
    return {colour: point for colour, point in zip(named, points) if np.isfinite(point).all()}


def base_camera_layout(rgb: Any, n_colours: int = len(COLOUR_NAMES)) -> dict[str, np.ndarray]:
    """``read_cube_layout`` of one base-camera frame ((H, W, 3), or a batch of one) with the camera's shipped
    calibration: what a policy reads from the harness's image alone."""
    frame = np.asarray(as_numpy(rgb))
    if frame.ndim == 4 and len(frame) == 1:
        frame = frame[0]
    return read_cube_layout(frame, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC, n_colours)


class CubeLayout:
    """Where each cube stands this episode, as the base camera showed it: each colour's (x, y) at its first sighting
    in a frame that shows more cubes than a cue does (``shown_at_once``: one for a sequence, the bunch for a bunch),
    so never where a cue showed it. The cubes stand still once out, so a placed colour is not read again, and once
    every colour is placed no frame is read at all (the image reader is the costly part). ``read`` turns one frame
    into colour -> (x, y) (``base_camera_layout`` by default; another reader may name objects by other words, as
    many as ``n_colours``). One layout serves one env; ``reset`` starts an episode."""

    def __init__(self, shown_at_once: int, n_colours: int = len(COLOUR_NAMES),
                 read: Callable[[Any], Mapping[str, np.ndarray]] | None = None):
        most = len(COLOUR_NAMES) if read is None else n_colours  # the default reader names colours only
        if not 1 <= shown_at_once < n_colours <= most:
            raise ValueError(f"need 1 <= shown_at_once < n_colours <= {most}, got shown_at_once="
                             f"{shown_at_once}, n_colours={n_colours}")
        self.shown_at_once, self.n_colours = shown_at_once, n_colours
        self.read = read or (lambda rgb: base_camera_layout(rgb, n_colours))
        self.places: dict[str, np.ndarray] = {}

    def reset(self) -> None:
        self.places = {}

    @property
    def complete(self) -> bool:
        return len(self.places) == self.n_colours

    def see(self, rgb: Any) -> None:
        """Place the colours one frame shows for the first time (nothing while it shows a cue's few cubes, or once
        every colour is placed)."""
        if self.complete:
            return
        seen = self.read(rgb)
        if len(seen) > self.shown_at_once:
            for colour, point in seen.items():
                self.places.setdefault(colour, np.asarray(point, dtype=np.float64))


def read_cue_set(rgb: np.ndarray, n_colours: int) -> tuple[str, ...] | None:
    """The colours of a cue shown together (BunchOfColors' arc): every cube the frame shows, left to right in the
    image; None when it shows none, or all ``n_colours`` (the cubes are out: no cue shows them all)."""
    named = name_blobs(rgb, n_colours)
    if not named or len(named) == n_colours:
        return None
    return tuple(sorted(named, key=lambda colour: named[colour][1]))


__all__ = ["CubeLayout", "LAYOUT_PLANE_Z", "LAYOUT_VOTE_SHARE", "SPLIT_MIN_PIXELS", "base_camera_layout", "cast_mask", "name_blobs", "read_cube_layout", "rgb_frame",
           "read_cue_set", "table_points"]
