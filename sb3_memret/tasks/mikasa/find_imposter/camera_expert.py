"""FindImposter's touch expert on what MIKASA's harness gives a policy alone: a protocol entry, not an upper bound.

``ImposterTouchController`` reads the objects' places from a simulated detector and the arm's joint velocities, so
its rows are a privileged upper bound. ``CameraImposterController`` touches the object it chooses as that expert does
(the one no fact of its prompt names, once every object is in sight; its ``chooser``) on the harness's inputs only:

- **the objects' places**: from the frame that shows all N (the cue shows N - 1; ``CubeLayout`` keeps them), cast
  onto the table with the camera's shipped calibration. Cubes of N colours are named by colour, as RememberColor's
  camera expert names them (on FindImposterColor9 the writer's reader, below, left one development seed's nine
  unplaced: 9 of 10 oracle episodes, against 10 of 10); objects of several shapes by the writer's reader of the
  family (``imposter_places``: from the frame that shows an object at each of the task's places, ``assign_shown``
  names each object in view by its top face's colour and its shading against the task's exemplars seen at its
  place, each a different candidate, touching objects cut apart);
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
from sb3_memret.tasks.mikasa.core.perception import REFERENCE_SIZE, cube_mask
from sb3_memret.tasks.mikasa.find_imposter.perception import NEAR_PLACE, ShapeExemplars, assign_shown

OCCUPIED_RADIUS = 3.0  # pixels: a place holds an object when one of its pixels lies this close to the place's centre
from sb3_memret.tasks.mikasa.find_imposter.task import ImposterTouchController
from sb3_memret.tasks.mikasa.remember.camera_expert import CameraTouchController


def exemplar_places(exemplars: ShapeExemplars, n_places: int) -> np.ndarray:
    """The (n_places, 2) image centres (row, col) of the places MIKASA stands a task's objects at: its exemplars'
    centres grouped within ``NEAR_PLACE`` pixels, the ``n_places`` largest groups' means (a few odd exemplars, of
    objects cut apart in calibration, make groups of one or two)."""
    sums: list[np.ndarray] = []  # each group's summed centres ...
    counts: list[int] = []  # ... and its size
    for centre in np.asarray(exemplars.centres, dtype=np.float64):
        near = next((g for g in range(len(sums)) if np.linalg.norm(sums[g] / counts[g] - centre) <= NEAR_PLACE), None)
        if near is None:
            sums.append(centre.copy())
            counts.append(1)
        else:
            sums[near] += centre
            counts[near] += 1
    if len(sums) < n_places:
        raise ValueError(f"the exemplars show {len(sums)} places; the task stands {n_places} objects")
    largest = np.argsort(counts, kind="stable")[::-1][:n_places]
    return np.array([sums[g] / counts[g] for g in largest])


def imposter_places(words: Sequence[str], candidates: Sequence[tuple[str | None, str | None]],
                    exemplars: ShapeExemplars) -> Callable[[Any], Mapping[str, np.ndarray]]:
    """A reader of one base-camera frame: word -> table (x, y) of every object, when the frame shows an object at
    every one of the task's places (``words[i]`` is ``candidates[i]``, as ``assign_shown`` takes them); else nothing.

    The cue shows N - 1 of the N objects and leaves a place empty; the choice fills every place. Over development
    seeds 5000-5009 of FindImposterShape9 every one of 183 choice frames had each place's centre within
    ``OCCUPIED_RADIUS`` of an object's pixel and none of 33 cue frames had. Objects that touch in the picture are cut
    apart by ``assign_shown`` (the largest group in two while fewer are in view than N): the rule before, a frame
    showing all N apart, left FindImposterShape9 with no frame to read at 6 of 10 seeds."""

    places = exemplar_places(exemplars, len(candidates))
    rows, cols = np.mgrid[:REFERENCE_SIZE, :REFERENCE_SIZE]
    near_place = [(rows + 0.5 - row) ** 2 + (cols + 0.5 - col) ** 2 <= OCCUPIED_RADIUS ** 2 for row, col in places]

    def read(rgb: Any) -> dict[str, np.ndarray]:
        frame = one_frame(rgb)
        mask = cube_mask(frame)
        if not all(mask[near].any() for near in near_place):
            return {}
        return named_places(frame, words, candidates, exemplars)

    return read


def one_frame(rgb: Any) -> np.ndarray:
    """One base-camera frame (H, W, 3) from an image or a batch of one; a ValueError for another size."""
    frame = np.asarray(as_numpy(rgb))
    frame = frame[0] if frame.ndim == 4 else frame
    if frame.shape[:2] != (REFERENCE_SIZE, REFERENCE_SIZE):
        raise ValueError(f"expected one {REFERENCE_SIZE}x{REFERENCE_SIZE} base-camera frame, got shape {frame.shape}")
    return frame


def named_places(frame: np.ndarray, words: Sequence[str], candidates: Sequence[tuple[str | None, str | None]],
                 exemplars: ShapeExemplars) -> dict[str, np.ndarray]:
    """word -> table (x, y) of every object in one frame as ``assign_shown`` names them (touching ones cut apart),
    cast onto the table with the shipped calibration; nothing unless it names all ``len(candidates)``."""
    assigned = assign_shown(frame, candidates, len(candidates), exemplars)
    if assigned is None:
        return {}
    centres = np.array([np.argwhere(seen.mask).mean(axis=0) + 0.5 for seen, _ in assigned])
    points = table_points(centres, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC, LAYOUT_PLANE_Z)
    return {words[j]: point for (_, j), point in zip(assigned, points) if np.isfinite(point).all()}


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


__all__ = ["CameraImposterController", "OCCUPIED_RADIUS", "exemplar_places", "imposter_places", "named_places",
           "one_frame"]
