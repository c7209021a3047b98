"""Where a carried cube is, for experts on the harness's inputs alone: seen once, then carried by the hand.

A camera-only expert sees the cube before it grips it; once in the fingers the cube is hidden by them and moves
with the hand. ``HeldCube`` keeps each env's cube: placed where it was first seen, gripped when the fingers' gap (the
harness's gripper opening) closes on it with the hand within reach of it, carried at the offset from the hand it was
gripped at, and left where it was last carried to when let go.
"""

from __future__ import annotations

import numpy as np

from sb3_memret.tasks.mikasa.core.carry_expert import CarryGains


class HeldCube:
    """Each env's cube (``places``, None until seen) and, while gripped, the hand's offset from it (``grips``);
    ``carry``'s ``held_gap`` and ``held_reach`` tell a grip, as for the detector's experts."""

    def __init__(self, carry: CarryGains):
        self.carry = carry
        self.places: list[np.ndarray | None] = []
        self.grips: list[np.ndarray | None] = []

    def reset(self, n_envs: int) -> None:
        self.places, self.grips = [None] * n_envs, [None] * n_envs

    def reset_env(self, i: int) -> None:
        self.places[i] = self.grips[i] = None

    def see(self, i: int, place: np.ndarray | None) -> None:
        """Place env ``i``'s cube where it was seen (xyz), unless it is placed already."""
        if self.places[i] is None and place is not None:
            self.places[i] = np.asarray(place, dtype=np.float64)

    def track(self, i: int, tcp: np.ndarray, gap: float) -> np.ndarray:
        """Env ``i``'s cube now (placed beforehand): gripped (the fingers closed on it, the hand within reach of it)
        it moves with the hand at the offset it was gripped at; let go, it stays where it was last carried to."""
        c = self.carry
        if not c.held_gap[0] <= gap <= c.held_gap[1]:
            self.grips[i] = None
        elif self.grips[i] is None and np.linalg.norm(tcp - self.places[i]) <= c.held_reach:
            self.grips[i] = tcp - self.places[i]
        if self.grips[i] is not None:
            self.places[i] = tcp - self.grips[i]
        return self.places[i]


__all__ = ["HeldCube"]
