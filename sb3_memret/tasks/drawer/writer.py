"""The drawer's writer rules: what it reads (the privileged state, or what a camera saw) as predicates, and the
relations they become (``the cube is in drawer layer 2.``, ``the robot is holding the cube.``)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from sb3_memret.tasks.drawer.cabinet import LAYERS, CabinetLayout
from sb3_memret.tasks.drawer.state import DrawerCubeState, layer_containing
from sb3_memret.memory.schema import NOTHING, MemoryType
from sb3_memret.memory.writer import UNKNOWN, Predicates
from sb3_memret.tasks.base import EnvFrame
from sb3_memret.tasks.drawer.prompts import OUTSIDE

# the drawer's relations: relation -> (memory type, relation name in the entry)
RELATIONS: dict[str, tuple[MemoryType, str]] = {
    "location": (MemoryType.OBJECT_LOCATION, "is_in"),
    "holding": (MemoryType.HOLDING, "holding"),
}



class BoundingBoxPredicateExtractor:
    """Reads the task's privileged state into predicates keyed (relation, entity).

    (location, target) is ``drawer layer N`` while the target's centre is in drawer N's
    interior box and ``outside`` otherwise; (holding, robot) is the target while both fingers
    press on it and ``nothing`` otherwise. The target is the object the instruction names
    (the cube in the seed's task).
    """

    def extract(self, state: DrawerCubeState, index: int = 0) -> Predicates:
        layer, target = int(state.target_in_layer[index]), state.target_name(index)
        return {
            ("location", target): f"drawer layer {layer}" if layer else OUTSIDE,
            ("holding", "robot"): target if bool(state.grasped[index]) else NOTHING,
        }


class ViewPredicateExtractor:
    """Reads only what a camera shows, never where the simulator placed anything: the observed-memory writer.

    A location is written for an object only while it is visible (``EnvFrame.views``): the layer is
    the drawer box, at its observed opening, that holds the detected position (``outside`` if none);
    the target's location is ``unknown`` while it is hidden. ``look_in`` reads the observation
    phase's views, in which drawer L alone stood open, so what is seen there is in drawer L.
    Holding is the gripper's touch (the grasp).
    """

    def __init__(self, layout: CabinetLayout | None = None):
        self.layout = layout or CabinetLayout()

    def extract(self, frame: EnvFrame) -> Predicates:
        if frame.views is None:
            raise ValueError("the frame carries no views: the observed-memory writer reads what a camera sees")
        opening = np.asarray(frame.obs["extra"]["drawer_opening"])[0]
        boxes = np.stack([np.stack(self.layout.inner_box(layer, float(opening[layer - 1]))) for layer in LAYERS])
        target = frame.state.target_name()
        predicates: Predicates = {("location", target): UNKNOWN}
        for name, detection in zip(frame.state.object_names[0], frame.views):
            if detection[0] > 0.5:
                layer = int(layer_containing(detection[None, 1:4].astype(np.float64), boxes[None])[0])
                predicates[("location", str(name))] = f"drawer layer {layer}" if layer else OUTSIDE
        predicates[("holding", "robot")] = target if bool(frame.state.grasped[0]) else NOTHING
        return predicates

    @staticmethod
    def look_in(views: np.ndarray, names: Sequence[str], layers: Sequence[int] = LAYERS) -> Predicates:
        """Predicates from ``views`` (drawers looked into, objects, 8), the drawers ``layers`` in that order
        (all of them by default): each object seen with drawer L open is in L."""
        if len(views) != len(layers):
            raise ValueError(f"{len(views)} views for the drawers {list(layers)}: one view per drawer looked into")
        predicates: Predicates = {}
        for layer, view in zip(layers, views):
            for name, detection in zip(names, view):
                if detection[0] > 0.5:
                    predicates[("location", str(name))] = f"drawer layer {layer}"
        return predicates


class DrawerWriter:
    """Reads the drawer's predicates at the end of each chunk: from the privileged state (``seeded``)
    or from what a camera sees (``observed``)."""

    relations = RELATIONS

    def __init__(self, source: str = "seeded"):
        self.source = source
        self.extractor = BoundingBoxPredicateExtractor() if source == "seeded" else ViewPredicateExtractor()

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        return [(frame.steps, self.extractor.extract(frame if self.source == "observed" else frame.state))]


__all__ = ["RELATIONS", "BoundingBoxPredicateExtractor", "DrawerWriter", "ViewPredicateExtractor"]
