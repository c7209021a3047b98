"""RememberShape's and RememberShapeAndColor's touch expert on what MIKASA's harness gives a policy alone: a protocol
entry, not an upper bound.

Their detector experts (``ScriptedTouchController``) read every object's pose from the simulator. Here the objects are
placed as RememberColor's camera expert places cubes (``CameraTouchController``: from the first frame that shows
more objects than the cue's one, cast onto the table with the shipped calibration; the hand's motion dead-reckoned),
and named as FindImposter's camera expert names the same objects (``assign_shown``): MIKASA lays out RememberShape's and
FindImposter's N objects at the same places (a row for three, an arc for more), so each object is named by its top
face's colour and its shading against the shipped exemplars of the FindImposter task with the same objects
(``exemplars_for``: calibration frames of development seeds 6000-6199, never a protocol seed).

Measured at development seeds 5000-5009
(``lab/2026-12-05-seven-more-families-on-the-cameras/shape_layout_probe.py``), FindImposter's own reader
(``imposter_places``, which reads only a frame that shows all N apart): every object placed and named, within
1.2 cm, at every seed on RememberShape3 and 5 and RememberShapeAndColor3x2; RememberShapeAndColor3x3 at 8 of 10
(one object named wrong); RememberShape9 at 5 of 10 and RememberShapeAndColor5x3 at 1 of 10 (neighbours on the arc
touch in the picture, so no frame shows all apart).

So the reader here (``remember_places``) does not wait for a frame that shows all N apart, as FindImposter's must
(its cue shows N - 1, which would read as N): the cue here shows one object, so any frame with more in view shows
the choice, and ``assign_shown`` cuts touching objects apart (the largest group in two while fewer are in view than
N). Over seeds 5000-5019 every object was placed within 4 cm at 19 of 20 seeds on RememberShape9 (one seed with
one wrong), 18 of 20 on RememberShapeAndColor3x3 (2 read nothing), 7 of 20 on RememberShapeAndColor5x3 (11 with
some of the fifteen wrong, 2 read nothing).
"""

from __future__ import annotations

import re
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES
from sb3_memret.tasks.mikasa.core.touch_expert import TouchGains
from sb3_memret.tasks.mikasa.find_imposter.camera_expert import named_places, one_frame
from sb3_memret.tasks.mikasa.find_imposter.perception import ShapeExemplars, objects_in_view, task_exemplars
from sb3_memret.tasks.mikasa.remember.camera_expert import CameraTouchController

_REMEMBER_ID = re.compile(r"^Remember(Shape|ShapeAndColor)([0-9x]+)(?:-Long)?-VLA-v0$")


def _family(env_id: str) -> tuple[str, str]:
    match = _REMEMBER_ID.match(env_id)
    if match is None:
        raise ValueError(f"{env_id!r} is not a RememberShape or RememberShapeAndColor task (their ids match "
                         f"{_REMEMBER_ID.pattern})")
    return match[1], match[2]


def exemplars_for(env_id: str) -> str:
    """The FindImposter task whose shipped exemplars show a Remember task's objects at its places
    (``RememberShape5-Long-VLA-v0`` -> ``FindImposterShape5-VLA-v0``); a ValueError for another id."""
    family, size = _family(env_id)
    return f"FindImposter{family}{size}-VLA-v0"


def candidates(env_id: str, words: Sequence[str]) -> list[tuple[str | None, str | None]]:
    """(colour, shape) of each word's object, as ``assign_shown`` takes them: RememberShape's are all one blue
    (``t shape`` -> (None, ``t shape``)), RememberShapeAndColor's words name both (``red t shape``)."""
    if _family(env_id)[0] == "Shape":
        return [(None, word) for word in words]
    return [tuple(word.split(" ", 1)) for word in words]


def remember_places(words: Sequence[str], candidates: Sequence[tuple[str | None, str | None]],
                    exemplars: ShapeExemplars) -> Callable[[Any], Mapping[str, np.ndarray]]:
    """A reader of one base-camera frame: word -> table (x, y) of every object, when it shows more than the cue's one
    (``words[i]`` is ``candidates[i]``, as ``assign_shown`` takes them; touching objects cut apart); else nothing."""

    n_colours = 1 + max(COLOUR_NAMES.index(colour or "blue") for colour, _ in candidates)

    def read(rgb: Any) -> dict[str, np.ndarray]:
        frame = one_frame(rgb)
        return named_places(frame, words, candidates, exemplars) if len(objects_in_view(frame, n_colours)) >= 2 else {}

    return read


def shape_places(env_id: str, words: Sequence[str]) -> Callable[[Any], Mapping[str, np.ndarray]]:
    """The reader of one base-camera frame that places ``words``' objects of ``env_id`` (the module docstring says
    how)."""
    return remember_places(words, candidates(env_id, words), task_exemplars(exemplars_for(env_id)))


class CameraShapeTouchController(CameraTouchController):
    """Touches the object its prompt's ``field`` word names (``shape``, ``object``), reading only the base camera's
    image and the hand's pose; ``read_layout`` names the objects (``shape_places``)."""

    def __init__(self, words: Sequence[str], prompt_template: PromptTemplate, field: str, paced_every: int,
                 read_layout: Callable[[Any], Mapping[str, np.ndarray]], chunk_len: int = 8,
                 gains: TouchGains | None = None, default: str | None = None, wait_for_all: bool = False):
        super().__init__(words, prompt_template, paced_every, chunk_len, gains, default, wait_for_all, read_layout)
        self.field = field


__all__ = ["CameraShapeTouchController", "candidates", "exemplars_for", "remember_places", "shape_places"]
