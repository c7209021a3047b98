"""The rule-based memory writer: simulator state -> predicates -> memory entries on change."""

from __future__ import annotations

from typing import Mapping, Protocol, Sequence

import numpy as np

from sb3_memret.envs.cabinet import LAYERS, CabinetLayout
from sb3_memret.envs.drawer_cube import DrawerCubeState, layer_containing
from sb3_memret.memory.schema import NOTHING, OUTSIDE, MemoryEntry, MemoryType
from sb3_memret.tasks.base import EnvFrame, Predicates

UNKNOWN = "unknown"

# the drawer's relations: relation -> (memory type, relation name in the entry)
RELATIONS: dict[str, tuple[MemoryType, str]] = {
    "location": (MemoryType.OBJECT_LOCATION, "is_in"),
    "holding": (MemoryType.HOLDING, "holding"),
}


class TextEncoder(Protocol):
    def encode(self, texts: list[str]) -> np.ndarray: ...


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


class EventCompiler:
    """Turns predicate changes into complete memory entries; unchanged predicates emit nothing.

    Every predicate starts as ``unknown``, so the first reading of an episode is written.
    ``relations`` maps each predicate relation to the memory type and entry relation it becomes
    (a task's writer declares its own; the drawer's by default).
    """

    def __init__(self, encoder: TextEncoder | None = None,
                 relations: Mapping[str, tuple[MemoryType, str]] = RELATIONS):
        self.encoder = encoder
        self.relations = relations
        self._previous: Predicates = {}

    def reset(self) -> None:
        self._previous = {}

    def update(self, predicates: Predicates, timestamp: int) -> list[MemoryEntry]:
        entries = []
        for (relation, entity), value in predicates.items():
            if relation not in self.relations:
                raise ValueError(f"unknown predicate relation {relation!r}; expected one of {sorted(self.relations)}")
            if value == UNKNOWN or self._previous.get((relation, entity), UNKNOWN) == value:
                continue
            mtype, entry_relation = self.relations[relation]
            entries.append(MemoryEntry.create(mtype, entity, entry_relation, value, timestamp))
        self._previous.update({key: value for key, value in predicates.items() if value != UNKNOWN})
        if entries and self.encoder is not None:
            vectors = self.encoder.encode([e.text for e in entries])
            entries = [e.with_embedding(v) for e, v in zip(entries, vectors)]
        return entries
