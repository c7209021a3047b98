"""FindImposter's touch expert on what MIKASA's harness gives a policy alone: a protocol entry, not an upper bound.

``ImposterTouchController`` reads the objects' places from a simulated detector and the arm's joint velocities, so
its rows are a privileged upper bound. ``CameraImposterController`` touches the object it chooses as that expert does
(the one no fact of its prompt names, once every object is in sight; its ``chooser``) on the harness's inputs only:

- **the objects' places**: from the frame that shows all N (the cue shows N - 1; ``CubeLayout`` keeps them), cast
  onto the table with the camera's shipped calibration. Cubes of N colours are named by colour, as RememberColor's
  camera expert names them (on FindImposterColor9 the writer's reader, below, left one development seed's nine
  unplaced: 9 of 10 oracle episodes, against 10 of 10); objects of several shapes by the writer's reader of the
  family (``imposter_places``: ``assign_shown`` names each object in view by its top face's colour and its shading
  against the task's exemplars seen at its place, each a different candidate);
- **the hand's motion**: dead-reckoned from its pose (``CameraTouchController``, RememberColor's camera expert, whose
  motion it is).
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import numpy as np

from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.carry_expert import REACH_X
from sb3_memret.tasks.mikasa.core.layout_perception import LAYOUT_PLANE_Z, CubeLayout, table_points
from sb3_memret.tasks.mikasa.core.touch_expert import TouchGains
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES
from sb3_memret.tasks.mikasa.find_imposter.perception import ShapeExemplars, assign_shown, objects_in_view
from sb3_memret.tasks.mikasa.find_imposter.task import ImposterTouchController
from sb3_memret.tasks.mikasa.remember.camera_expert import CameraTouchController


def imposter_places(words: Sequence[str], candidates: Sequence[tuple[str | None, str | None]],
                    exemplars: ShapeExemplars | None) -> Callable[[Any], Mapping[str, np.ndarray]]:
    """A reader of one base-camera frame: word -> table (x, y) of every object, when the frame shows all of them apart
    (``words[i]`` is ``candidates[i]``, as ``assign_shown`` takes them); else nothing."""

    n_colours = 1 + max(COLOUR_NAMES.index(colour or "blue") for colour, _ in candidates)

    def read(rgb: Any) -> dict[str, np.ndarray]:
        frame = np.asarray(as_numpy(rgb))
        frame = frame[0] if frame.ndim == 4 else frame
        # as many objects apart in view, before any is cut in two: ``assign_shown`` cuts the largest while fewer are
        # in view than it is asked for, so the cue's N - 1 would read as N
        if len(objects_in_view(frame, n_colours)) < len(candidates):
            return {}
        assigned = assign_shown(frame, candidates, len(candidates), exemplars)
        if assigned is None:
            return {}
        centres = np.array([np.argwhere(seen.mask).mean(axis=0) + 0.5 for seen, _ in assigned])
        points = table_points(centres, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC, LAYOUT_PLANE_Z)
        return {words[j]: point for (_, j), point in zip(assigned, points) if np.isfinite(point).all()}

    return read


class CameraImposterController(CameraTouchController):
    """Touches the object its prompt's facts do not name, reading only the base camera's image and the hand's pose.
    ``chooser``: the detector's expert of the task, which says which object (``_chosen``); its vocabulary, template
    and default are this controller's. ``read_places``: one frame -> word -> (x, y) (``imposter_places``; None:
    cubes by colour).
    ``paced_every``: the control steps executed between its calls."""

    def __init__(self, chooser: ImposterTouchController,
                 read_places: Callable[[Any], Mapping[str, np.ndarray]] | None, paced_every: int, chunk_len: int = 8):
        super().__init__(chooser.vocabulary, chooser.spec.prompt_template, paced_every, chunk_len,
                         gains=TouchGains(max_x=REACH_X), default=chooser.default, wait_for_all=True,
                         read_layout=read_places)
        self.chooser = chooser
        self.shown_at_once = len(chooser.vocabulary) - 1  # the cue shows every object but the imposter

    def reset(self, seeds: Sequence[int]) -> None:
        super().reset(seeds)
        self.layouts = [CubeLayout(self.shown_at_once, len(self.vocabulary), self.read_layout) for _ in seeds]

    def _chosen(self, parsed: Sequence[ParsedPrompt]) -> list[str | None]:
        return self.chooser._chosen(parsed)


__all__ = ["CameraImposterController", "imposter_places"]
