"""The closed paths MIKASA's TraceShape tasks trace, and how to recover one from where a cube was seen along it.

MIKASA draws a circle, a square or an equilateral triangle as ``NUM_WAYPOINTS`` (64) points at t = i / 64 around a
unit shape (``unit_shape``: the circle from angle 0, the square from its corner (-1, -1) along its sides counter-
clockwise, the triangle from its vertex at angle 0), scaled by a radius, turned by a rotation and moved to a centre.
Every such path is ``centre + M u(t)`` with ``M = [[a, -b], [b, a]]`` (a = r cos rot, b = r sin rot), linear in
(centre, a, b): ``fit_path`` recovers them from sightings at known t by least squares, for each shape, and keeps the
shape that fits best. A path is named by its shape, its centre and its start (``TracedPath``), in millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SHAPES: tuple[str, ...] = ("circle", "square", "triangle")  # MIKASA's SHAPE_CIRCLE, SHAPE_SQUARE, SHAPE_TRIANGLE
NUM_WAYPOINTS = 64  # MIKASA's NUM_WAYPOINTS: one a control step during the demonstration
NUM_CHECKPOINTS = 12  # MIKASA's NUM_CHECKPOINTS: every 5th waypoint from the first, checked for success
MIN_SIGHTINGS = 12  # fewer sightings than this (of 64): no path is read


def unit_shape(shape: str, t: np.ndarray) -> np.ndarray:
    """Points (N, 2) of the unit ``shape`` (radius 1, no rotation, centred at 0) at path fractions ``t`` in [0, 1)."""
    t = np.asarray(t, dtype=np.float64)
    if shape == "circle":
        return np.stack([np.cos(2 * np.pi * t), np.sin(2 * np.pi * t)], axis=1)
    if shape == "square":
        corners = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        side = np.minimum((t * 4).astype(int), 3)
        frac = t * 4 - side
        return corners[side] + (corners[(side + 1) % 4] - corners[side]) * frac[:, None]
    if shape == "triangle":
        angles = np.array([0.0, 2 * np.pi / 3, 4 * np.pi / 3])
        vertices = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        side = np.minimum((t * 3).astype(int), 2)
        frac = t * 3 - side
        return vertices[side] + (vertices[(side + 1) % 3] - vertices[side]) * frac[:, None]
    raise ValueError(f"unknown shape {shape!r}; expected one of {list(SHAPES)}")


def waypoint_fractions() -> np.ndarray:
    """MIKASA's path fractions of its 64 waypoints: i / 64."""
    return np.arange(NUM_WAYPOINTS) / NUM_WAYPOINTS


@dataclass(frozen=True)
class TracedPath:
    """One traced path: its shape, its centre and its start (x, y in millimetres, world frame)."""

    shape: str
    centre: tuple[int, int]
    start: tuple[int, int]

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"unknown shape {self.shape!r}; expected one of {list(SHAPES)}")

    @property
    def turn(self) -> np.ndarray:
        """``M`` (2x2): the scaled rotation that takes the unit shape's start to the start's offset from the centre."""
        offset = (np.asarray(self.start, dtype=np.float64) - np.asarray(self.centre)) / 1000.0
        unit = unit_shape(self.shape, np.zeros(1))[0]
        # M u0 = offset with M = [[a, -b], [b, a]]: solve for (a, b)
        a, b = np.linalg.solve(np.array([[unit[0], -unit[1]], [unit[1], unit[0]]]), offset)
        return np.array([[a, -b], [b, a]])

    def waypoints(self) -> np.ndarray:
        """The path's 64 waypoints (64, 2), metres, in MIKASA's order."""
        centre = np.asarray(self.centre, dtype=np.float64) / 1000.0
        return centre + unit_shape(self.shape, waypoint_fractions()) @ self.turn.T

    def checkpoints(self) -> np.ndarray:
        """MIKASA's 12 checkpoints (12, 2), metres: every 5th waypoint from the first."""
        step = max(1, NUM_WAYPOINTS // NUM_CHECKPOINTS)
        return self.waypoints()[::step][:NUM_CHECKPOINTS]

    def moved(self, dx_mm: int, dy_mm: int) -> "TracedPath":
        """The same path moved by (dx, dy) millimetres."""
        return TracedPath(self.shape, (self.centre[0] + dx_mm, self.centre[1] + dy_mm),
                          (self.start[0] + dx_mm, self.start[1] + dy_mm))


def fit_path(fractions: np.ndarray, points: np.ndarray, shapes: tuple[str, ...] = SHAPES) -> tuple[TracedPath, float]:
    """The path among ``shapes`` that best explains ``points`` (N, 2, metres) seen at path ``fractions`` (N,), and its
    RMS residual (metres): for each shape, centre and scaled rotation by linear least squares."""
    fractions, points = np.asarray(fractions, dtype=np.float64), np.asarray(points, dtype=np.float64)
    if len(fractions) != len(points) or len(points) < 3:
        raise ValueError(f"need at least 3 sightings with their fractions, got {len(points)} and {len(fractions)}")
    best: tuple[TracedPath, float] | None = None
    for shape in shapes:
        u = unit_shape(shape, fractions)
        rows = np.zeros((2 * len(u), 4))
        rows[0::2] = np.column_stack([np.ones(len(u)), np.zeros(len(u)), u[:, 0], -u[:, 1]])
        rows[1::2] = np.column_stack([np.zeros(len(u)), np.ones(len(u)), u[:, 1], u[:, 0]])
        (cx, cy, a, b), *_ = np.linalg.lstsq(rows, points.reshape(-1), rcond=None)
        residual = float(np.sqrt(np.mean((rows @ np.array([cx, cy, a, b]) - points.reshape(-1)) ** 2)))
        start = np.array([cx, cy]) + np.array([[a, -b], [b, a]]) @ unit_shape(shape, np.zeros(1))[0]
        path = TracedPath(shape, (int(round(cx * 1000)), int(round(cy * 1000))),
                          (int(round(start[0] * 1000)), int(round(start[1] * 1000))))
        if best is None or residual < best[1]:
            best = (path, residual)
    assert best is not None
    return best


__all__ = ["MIN_SIGHTINGS", "NUM_CHECKPOINTS", "NUM_WAYPOINTS", "SHAPES", "TracedPath", "fit_path", "unit_shape",
           "waypoint_fractions"]
