"""The colour-cue tasks' writer: the cue's colours as one fact per item, and, with progress, what has been done.

The cue's facts are worded with their item's ordinal, ``the first cue cube was red.``, ``the second cue cube was
blue.``: a sequence's items in the order the camera showed them, a bunch's (shown together) in palette order (red,
lime, blue, yellow, magenta, cyan, maroon, olive, teal). Each item is its own memory key, so the bank keeps them side
by side and retention decides about each.

Progress (``the red cube was touched.``, ``the button was pressed.``) is read from the base camera's cube layout and
the hand's pose (what MIKASA's harness gives a policy): the layout is each colour's first sighting in a frame showing
more cubes than the cue shows at once (``CubeLayout``: never the cue's place, which shows one cube at the table centre
or the bunch on an arc; the camera is read only until every cube is placed), a touch the TCP still (under 1 mm per
control step since the writer's last frame) within 1.8 cm of the point 2.5 cm above a seen cube's centre (MIKASA:
2 cm, every joint under 0.2 rad/s), a press the TCP within 3 cm of the button's axis and 2 cm over its cap (MIKASA:
6.5 and 2.5 cm), the button standing 4 cm from the seen cubes' mean toward the robot (MIKASA's placement).
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import numpy as np

from sb3_memret.controllers.base import as_numpy
from sb3_memret.memory.schema import Key, MemoryType
from sb3_memret.tasks.base import EnvFrame, Predicates
from sb3_memret.tasks.mikasa.core.layout_perception import LAYOUT_PLANE_Z, CubeLayout
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES
from sb3_memret.tasks.mikasa.core.sequence_expert import BUTTON_TOP_ABOVE_BASE, CUBE_TOUCH_OFFSET, ORDINALS, SequenceGains

CUE_ENTITY = "cue cube"  # the k-th item's entity is "{ordinal} cue cube"
CUE_FACT = "the {ordinal} cue cube was {colour}."
TOUCHED, PRESSED = "touched", "pressed"  # the TASK_PROGRESS values, worded by PROGRESS_WORDINGS
PROGRESS_WORDINGS = {(MemoryType.TASK_PROGRESS, TOUCHED): "the {entity} was touched.",
                     (MemoryType.TASK_PROGRESS, PRESSED): "the {entity} was pressed."}
BUTTON_BASE_Z = 0.015  # MIKASA's button base centre height
BUTTON_TOWARD_ROBOT = 0.04  # MIKASA places the button at the cubes' mean position, this far toward the robot (-x)
N_COLOURS = 9  # every colour-cue task has all nine cubes


def item_entity(k: int) -> str:
    """The entity of the cue's ``k``-th item (0-based): ``first cue cube``, ``second cue cube``, ..."""
    return f"{ORDINALS[k]} {CUE_ENTITY}"


def item_key(k: int) -> Key:
    return (MemoryType.OTHER, item_entity(k), "was")


def sequence_facts(colours: Sequence[str]) -> list[str]:
    """One fact per cue item, in the given order."""
    return [CUE_FACT.format(ordinal=ORDINALS[k], colour=c) for k, c in enumerate(colours)]


def button_place(places: Mapping[str, np.ndarray]) -> np.ndarray:
    """The button's base centre (x, y, z) from the nine cubes' places: MIKASA stands it at their mean position,
    ``BUTTON_TOWARD_ROBOT`` toward the robot."""
    x, y = np.mean(list(places.values()), axis=0) - (BUTTON_TOWARD_ROBOT, 0.0)
    return np.array([x, y, BUTTON_BASE_Z])


def in_palette_order(colours: Sequence[str]) -> tuple[str, ...]:
    """A bunch's colours in the order its facts number them."""
    return tuple(sorted(colours, key=COLOUR_NAMES.index))


class SequenceWriter:
    """Writes the cue's facts from the base camera's percepts: one by one (``together=False``), each item at the
    control step the camera first showed its colour alone at the centre (MIKASA draws the sequence without
    replacement, so a colour not yet seen this episode is the next item; a frame read as nothing changes nothing);
    together, every item at the first step the camera showed exactly ``n_items`` cubes (a bunch partly hidden is not
    read). One writer serves one env; the reset frame (``steps == 0``) starts its episode.

    With ``progress``, it also writes ``the {colour} cube was touched.`` and ``the button was pressed.`` at the end of
    the chunk whose last frame shows them (the module docstring says how): those frames must carry the base camera's
    image (``sensor_data/base_camera/rgb``, until every cube is placed) and the hand's pose (``extra/tcp_pose``);
    ``read_layout`` turns an image into colour -> table (x, y) (``base_camera_layout`` by default)."""

    def __init__(self, n_items: int = 3, progress: bool = False, gains: SequenceGains | None = None,
                 together: bool = False, read_layout: Callable[[Any], Mapping[str, np.ndarray]] | None = None):
        if not 1 <= n_items < N_COLOURS:
            raise ValueError(f"n_items must be in 1..{N_COLOURS - 1}, got {n_items}")
        self.n_items, self.progress, self.together = n_items, progress, together
        self.gains = gains or SequenceGains()
        self.shown_at_once = n_items if together else 1  # the most cubes a cue frame shows
        self.relations = {"cue": (MemoryType.OTHER, "was")}
        if progress:
            self.relations.update({TOUCHED: (MemoryType.TASK_PROGRESS, "was"),
                                   PRESSED: (MemoryType.TASK_PROGRESS, "was")})
        self.seen: list[str] = []
        self.layout = CubeLayout(self.shown_at_once, N_COLOURS, read_layout)
        self.touched: list[str] = []
        self.pressed = False
        self.last_tcp: np.ndarray | None = None  # the hand's position at the last frame read

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self.seen, self.touched, self.pressed, self.last_tcp = [], [], False, None
            self.layout.reset()
        out = [(step, predicates) for step, seen in frame.timed_percepts() for predicates in self._cue(seen)]
        if self.progress:
            out += [(frame.steps, predicates) for predicates in self._progress(frame)]
        return out

    def _cue(self, seen: str | Sequence[str] | None) -> list[Predicates]:
        """The items one percept adds: a new colour of a sequence, or a whole bunch."""
        if seen is None or len(self.seen) >= self.n_items:
            return []
        if self.together:
            if len(seen) != self.n_items:
                return []
            self.seen = list(in_palette_order(seen))
            return [{("cue", item_entity(k)): colour for k, colour in enumerate(self.seen)}]
        if seen in self.seen:
            return []
        self.seen.append(str(seen))
        return [{("cue", item_entity(len(self.seen) - 1)): seen}]

    def _progress(self, frame: EnvFrame) -> list[Predicates]:
        """What the frame shows was done, not written before: a touch of a seen cube, the press."""
        if not self.layout.complete:
            try:
                rgb = frame.obs["sensor_data"]["base_camera"]["rgb"]
            except (KeyError, TypeError):
                raise ValueError("a progress writer reads the base camera's image (sensor_data/base_camera/rgb) until "
                                 "it has placed every cube; this frame has none") from None
            self.layout.see(rgb)
        places = self.layout.places
        g = self.gains
        tcp = as_numpy(frame.obs["extra"]["tcp_pose"]).reshape(-1)[:3].astype(np.float64)
        moved = np.inf if self.last_tcp is None else np.linalg.norm(tcp - self.last_tcp) / max(frame.steps, 1)
        self.last_tcp = tcp
        static = moved <= g.still_step
        if not places or not static:  # the cue or the delay, or the arm moving
            return []
        done: list[Predicates] = []
        for colour, (x, y) in places.items():
            touch_point = np.array([x, y, LAYOUT_PLANE_Z + CUBE_TOUCH_OFFSET])
            if colour not in self.touched and np.linalg.norm(tcp - touch_point) < g.touch_tol:
                self.touched.append(colour)
                done.append({(TOUCHED, f"{colour} cube"): TOUCHED})
        if self.touched and not self.pressed and self.layout.complete:
            button = button_place(places)
            top = button[2] + BUTTON_TOP_ABOVE_BASE
            if np.linalg.norm(tcp[:2] - button[:2]) < g.press_xy and tcp[2] <= top + g.press_seen:
                self.pressed = True
                done.append({(PRESSED, "button"): PRESSED})
        return done


__all__ = ["BUTTON_BASE_Z", "BUTTON_TOWARD_ROBOT", "CUE_ENTITY", "CUE_FACT", "N_COLOURS", "PRESSED", "PROGRESS_WORDINGS",
           "SequenceWriter", "TOUCHED", "button_place", "in_palette_order", "item_entity", "item_key",
           "sequence_facts"]
