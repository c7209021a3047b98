"""The ShellGame writer (``CupWriter``): where each ball's cup stands, read from the base camera alone, through the
shuffle."""

from __future__ import annotations

import numpy as np

from sb3_memret.memory.schema import MemoryType
from sb3_memret.tasks.base import EnvFrame, Predicates
from sb3_memret.tasks.mikasa.shell_game.variants import BALL, RELATION, SIDES, ball_entity
from sb3_memret.tasks.mikasa.shell_game.tracking import (CameraFrame, MAX_CUP_AREA, REST_TOL, ball_on_table,
                                                         cups_on_table, follow, least_moves)


class CupWriter:
    """Writes, for each ball, ``the {ball} is under the {side} cup.`` from the base camera's frames (one
    ``CameraFrame`` per control step): the ball's place from the cue, its cup's place in the row once the cups
    have come down, and (``shuffles``) again whenever the tracked cups rest after a swap. One writer serves one
    env; the reset frame (``steps == 0``) starts its episode."""

    relations = {BALL: (MemoryType.OTHER, RELATION)}

    def __init__(self, colours: tuple[str, ...], shuffles: bool):
        self.colours, self.shuffles = colours, shuffles
        self._start()

    def _start(self) -> None:
        self.reference: np.ndarray | None = None  # the latest frame before the cups came down
        self.balls: dict[str, np.ndarray] = {}  # colour -> where the ball lay
        self.places: np.ndarray | None = None  # (3, 2): the row's places, left to right, when the cups came down
        self.cups: np.ndarray | None = None  # (3, 2): where each cup is now, cup i the one first seen at place i
        self.under: dict[str, int] = {}  # colour -> the cup hiding that ball
        self.largest = 0  # the largest cup's pixels at the first sighting
        self.done = False  # nothing more to read this episode

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self._start()
        out = []
        for step, seen in frame.timed_percepts():
            facts = self.see(seen)
            if facts:
                out.append((step, facts))
        return out

    def see(self, seen: CameraFrame) -> Predicates | None:
        """The facts one frame lets the writer state (None: none yet, or nothing new to read)."""
        if self.done:
            return None
        if self.places is None:
            return self._before_cups(seen)
        cups = cups_on_table(seen, self.reference, MAX_CUP_AREA * self.largest)
        if len(cups) != len(SIDES):
            return None  # cups merged, hidden or joined by something else in view: skip the frame
        followed = follow(self.cups, np.stack([point for point, _ in cups]))
        if followed is None:
            return None  # no swap of MIKASA's explains this frame: keep the cups where they were last seen
        self.cups = followed
        return self._facts()

    def _before_cups(self, seen: CameraFrame) -> Predicates | None:
        cups = [] if self.reference is None else cups_on_table(seen, self.reference)
        if not cups:  # the cue: the cups are out of sight; the balls show where they lie
            self.reference = np.asarray(seen.rgb)
            for colour in self.colours:
                point = ball_on_table(seen, colour)
                if point is not None:
                    self.balls[colour] = point
            return None
        if len(cups) != len(SIDES):
            return None  # wait for a frame that shows the three cups apart
        if len(self.balls) != len(self.colours):
            self.done = True  # a ball was never seen: no cup to name
            return None
        order = np.argsort([point[1] for point, _ in cups])  # left (-y) to right
        self.places = np.stack([cups[j][0] for j in order])
        self.cups, self.largest = self.places.copy(), max(size for _, size in cups)
        match = least_moves(np.stack([self.balls[c] for c in self.colours]), self.places)
        self.under = dict(zip(self.colours, match))  # each ball under the cup nearest to where it lay
        facts = self._facts()
        self.done = not self.shuffles
        return facts

    def _facts(self) -> Predicates | None:
        """Each ball's cup's place, when every cup rests at a different place of the row; else None."""
        gaps = np.linalg.norm(self.cups[:, None] - self.places[None], axis=-1)
        at = gaps.argmin(axis=1)
        if len(set(at.tolist())) != len(SIDES) or gaps[np.arange(len(at)), at].max() > REST_TOL:
            return None
        n = len(self.colours)
        return {(BALL, ball_entity(colour, n)): f"{SIDES[at[cup]]} cup" for colour, cup in self.under.items()}


__all__ = ["CupWriter"]
