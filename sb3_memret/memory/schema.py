"""Typed memory entries and the per-type templates that turn them into prompt text.

Texts are lowercase and end with a full stop, exactly as the controller's training prompts:
a memory whose text drifts from these templates is refused by ``sb3_memret.controllers.prompts``.
"""

from __future__ import annotations

import enum
from typing import Mapping
from dataclasses import dataclass, replace

import numpy as np


class MemoryType(enum.IntEnum):
    OBJECT_LOCATION = 0
    HOLDING = 1
    COUNT = 2
    TASK_PROGRESS = 3
    FAILURE = 4
    OTHER = 5


NOTHING = "nothing"

# One template per type; a few values read better with their own wording (a task adds its own: ``Task.wordings``).
TEMPLATES: dict[MemoryType, str] = {
    MemoryType.OBJECT_LOCATION: "the {entity} is in {value}.",
    MemoryType.HOLDING: "the robot is holding the {value}.",
    MemoryType.COUNT: "there are {value} {entity} objects.",
    MemoryType.TASK_PROGRESS: "the {entity} is {value}.",
    MemoryType.FAILURE: "the robot failed to {relation} the {entity}.",
    MemoryType.OTHER: "the {entity} {relation} {value}.",
}
SPECIAL_TEXTS: dict[tuple[MemoryType, str], str] = {
    (MemoryType.HOLDING, NOTHING): "the robot is holding nothing.",
}

# A fixed prior on how much each type tends to matter; the retention network learns the rest.
IMPORTANCE: dict[MemoryType, float] = {
    MemoryType.OBJECT_LOCATION: 1.0,
    MemoryType.HOLDING: 0.8,
    MemoryType.FAILURE: 0.7,
    MemoryType.TASK_PROGRESS: 0.6,
    MemoryType.COUNT: 0.5,
    MemoryType.OTHER: 0.3,
}

Key = tuple[MemoryType, str, str]

# What a memory's age counts: control steps since it was written, or episodes (a household's tasks).
AGE_UNITS = ("steps", "tasks")


def check_age_unit(unit: str) -> str:
    if unit not in AGE_UNITS:
        raise ValueError(f"unknown age unit {unit!r}; expected one of {list(AGE_UNITS)}")
    return unit


Wordings = Mapping[tuple[MemoryType, str], str]  # (type, value) -> the template that value reads better in


def linearize(mtype: MemoryType, entity: str, relation: str, value: str, wordings: Wordings | None = None) -> str:
    """The memory's text, from ``wordings``' template for its type and value, else the schema's; lowercase words
    only."""
    for word in (entity, relation, value):
        if not word or word != word.lower() or word.strip() != word or "." in word:
            raise ValueError(f"memory fields must be non-empty lowercase words without full stops, got {word!r}")
    template = (wordings or {}).get((mtype, value)) or SPECIAL_TEXTS.get((mtype, value), TEMPLATES[MemoryType(mtype)])
    return template.format(entity=entity, relation=relation.replace("_", " "), value=value)


@dataclass
class MemoryEntry:
    """One fact in the bank. Its key (type, entity, relation) identifies the state it describes."""

    type: MemoryType
    entity: str
    relation: str
    value: str
    timestamp: int
    text: str
    embedding: np.ndarray | None = None
    importance: float = 0.0
    usage_count: int = 0
    last_used: int = -1  # time of the last retrieval, -1 if never retrieved
    episode: int = 0  # the episode it was written in (a household's task), for ages counted in tasks

    @property
    def key(self) -> Key:
        return (self.type, self.entity, self.relation)

    @classmethod
    def create(cls, mtype: MemoryType, entity: str, relation: str, value: str, timestamp: int,
               embedding: np.ndarray | None = None, wordings: Wordings | None = None) -> "MemoryEntry":
        """A complete entry: text from the template (``linearize``), importance from the type prior, unused."""
        mtype = MemoryType(mtype)
        return cls(mtype, entity, relation, value, int(timestamp), linearize(mtype, entity, relation, value, wordings),
                   embedding, IMPORTANCE[mtype], 0)

    def with_embedding(self, embedding: np.ndarray) -> "MemoryEntry":
        return replace(self, embedding=np.asarray(embedding, dtype=np.float32))
