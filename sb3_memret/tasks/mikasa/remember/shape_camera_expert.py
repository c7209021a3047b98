"""RememberShape's and RememberShapeAndColor's touch expert on what MIKASA's harness gives a policy alone: a protocol
entry, not an upper bound.

Their detector experts (``ScriptedTouchController``) read every object's pose from the simulator. Here the objects are
placed as RememberColor's camera expert places cubes (``CameraTouchController``: from the first frame that shows
more objects than the cue's one, cast onto the table with the shipped calibration; the hand's motion dead-reckoned),
and named as FindImposter's camera expert names its objects (``assign_shown``: each by its top face's colour and its
shading against exemplars seen at its place), against exemplars of the task's own choice frames (``exemplars_for``:
calibration frames of development seeds 6000-6199, never a protocol seed;
``scripts/calibrate_imposter.py calibrate-remember``).

The cue shows one object, so any frame with more in view shows the choice, and touching objects are cut apart colour
by colour until each colour has its count (``assign_shown(..., by_colour=True)``). Two earlier readers fell short on
RememberShapeAndColor5x3, over development seeds 5000-5039 (``lab/2026-12-06-remember-shape-and-color-on-the-cameras``):

- FindImposter's exemplars, from its cue frames: none had been seen at 7 of the 15 places (neighbours there touch
  and were skipped), and same-coloured pairs swapped shapes at 7 of the first 12 seeds;
- cutting the largest group in the picture: a near object was cut while two far ones stayed merged, and 4 of 40
  seeds read nothing.
"""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES
from sb3_memret.tasks.mikasa.core.touch_expert import TouchGains
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.layout_perception import LAYOUT_PLANE_Z, table_points
from sb3_memret.tasks.mikasa.find_imposter.camera_expert import one_frame
from sb3_memret.tasks.mikasa.find_imposter.perception import ShapeExemplars, assign_shown, objects_in_view
from sb3_memret.tasks.mikasa.remember.camera_expert import CameraTouchController

REMEMBER_EXEMPLARS_DIR = Path(__file__).resolve().parents[1] / "assets" / "remember_exemplars"
_REMEMBER_ID = re.compile(r"^Remember(Shape|ShapeAndColor)([0-9x]+)(?:-Long)?-VLA-v0$")


def _family(env_id: str) -> tuple[str, str]:
    match = _REMEMBER_ID.match(env_id)
    if match is None:
        raise ValueError(f"{env_id!r} is not a RememberShape or RememberShapeAndColor task (their ids match "
                         f"{_REMEMBER_ID.pattern})")
    return match[1], match[2]


def exemplars_for(env_id: str) -> Path:
    """The shipped exemplars of a Remember task's objects at its choice (``RememberShape5-Long-VLA-v0`` ->
    ``REMEMBER_EXEMPLARS_DIR/RememberShape5-VLA-v0.npz``: a -Long variant lays them out alike); a ValueError for
    another id."""
    family, size = _family(env_id)
    return REMEMBER_EXEMPLARS_DIR / f"Remember{family}{size}-VLA-v0.npz"


@lru_cache(maxsize=None)
def _exemplars(path: Path) -> ShapeExemplars:
    return ShapeExemplars.load(path)


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
        if len(objects_in_view(frame, n_colours)) < 2:
            return {}
        assigned = assign_shown(frame, candidates, len(candidates), exemplars, by_colour=True)
        if assigned is None:
            return {}
        centres = np.array([np.argwhere(seen.mask).mean(axis=0) + 0.5 for seen, _ in assigned])
        points = table_points(centres, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC, LAYOUT_PLANE_Z)
        return {words[j]: point for (_, j), point in zip(assigned, points) if np.isfinite(point).all()}

    return read


def shape_places(env_id: str, words: Sequence[str]) -> Callable[[Any], Mapping[str, np.ndarray]]:
    """The reader of one base-camera frame that places ``words``' objects of ``env_id`` (the module docstring says
    how)."""
    return remember_places(words, candidates(env_id, words), _exemplars(exemplars_for(env_id)))


class CameraShapeTouchController(CameraTouchController):
    """Touches the object its prompt's ``field`` word names (``shape``, ``object``), reading only the base camera's
    image and the hand's pose; ``read_layout`` names the objects (``shape_places``)."""

    def __init__(self, words: Sequence[str], prompt_template: PromptTemplate, field: str, paced_every: int,
                 read_layout: Callable[[Any], Mapping[str, np.ndarray]], chunk_len: int = 8,
                 gains: TouchGains | None = None, default: str | None = None, wait_for_all: bool = False):
        super().__init__(words, prompt_template, paced_every, chunk_len, gains, default, wait_for_all, read_layout)
        self.field = field


__all__ = ["REMEMBER_EXEMPLARS_DIR", "CameraShapeTouchController", "candidates", "exemplars_for", "remember_places",
           "shape_places"]
