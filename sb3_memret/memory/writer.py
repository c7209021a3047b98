"""The rule-based memory writer's generic half: predicates (what a task's writer read) -> memory entries on change.
What a task reads, and which relations its predicates become, is the task's (``Task.writer``)."""

from __future__ import annotations

from typing import Mapping, Protocol

import numpy as np

from sb3_memret.memory.schema import MemoryEntry, MemoryType, Wordings

UNKNOWN = "unknown"
Predicates = dict[tuple[str, str], str]  # (relation, entity) -> value: what a task's writer read in one frame


class TextEncoder(Protocol):
    def encode(self, texts: list[str]) -> np.ndarray: ...


class EventCompiler:
    """Turns predicate changes into complete memory entries; unchanged predicates emit nothing.

    Every predicate starts as ``unknown``, so the first reading of an episode is written.
    ``relations`` maps each predicate relation to the memory type and entry relation it becomes
    (the task's writer declares them: ``Writer.relations``); ``wordings`` are the task's own templates for
    some values (``Task.wordings``).
    """

    def __init__(self, encoder: TextEncoder | None, relations: Mapping[str, tuple[MemoryType, str]],
                 wordings: Wordings | None = None):
        self.encoder = encoder
        self.relations = relations
        self.wordings = wordings
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
            entries.append(MemoryEntry.create(mtype, entity, entry_relation, value, timestamp, wordings=self.wordings))
        self._previous.update({key: value for key, value in predicates.items() if value != UNKNOWN})
        if entries and self.encoder is not None:
            vectors = self.encoder.encode([e.text for e in entries])
            entries = [e.with_embedding(v) for e, v in zip(entries, vectors)]
        return entries
