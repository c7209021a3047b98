"""A bounded memory bank with in-place replacement of state-like facts and scored eviction."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from sb3_memret.memory.encoder import EMBEDDING_DIM
from sb3_memret.memory.schema import Key, MemoryEntry

KeepScorer = Callable[[Sequence[MemoryEntry]], np.ndarray]


def importance_scorer(entries: Sequence[MemoryEntry]) -> np.ndarray:
    """Keep-scores from the fixed per-type importance prior (before a retention net is trained)."""
    return np.array([e.importance for e in entries], dtype=np.float64)


@dataclass(frozen=True)
class WriteOutcome:
    """Where a write landed: its slot (None if the newcomer itself was the one dropped),
    whether it replaced the entry with the same key, and what was evicted to make room."""

    slot: int | None
    replaced: bool = False
    evicted: MemoryEntry | None = None


@dataclass(frozen=True)
class BankView:
    """Fixed-shape arrays of the bank for the policy; slot i is ``bank.entries[i]``."""

    embeddings: np.ndarray  # (capacity, 384) float32, zeros in empty slots
    mask: np.ndarray  # (capacity,) bool, True where a slot holds an entry
    type_ids: np.ndarray  # (capacity,) int64
    age: np.ndarray  # (capacity,) float32, steps since the entry was written (or the ages given to ``view``)
    usage: np.ndarray  # (capacity,) float32, times the entry was retrieved


class MemoryBank:
    """At most ``capacity`` entries, in stable slots.

    A fact whose key (type, entity, relation) is already stored replaces that entry in place
    (the cube is never in two drawers at once). When the bank is full, the newcomer competes
    with the stored entries: the keep-scorer scores all ``capacity + 1`` and the lowest is
    dropped, so a low-value fact cannot flush a valuable one; if the newcomer scores lowest it
    is not stored.
    """

    def __init__(self, capacity: int, embedding_dim: int = EMBEDDING_DIM):
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
            raise ValueError(f"capacity must be a positive int, got {capacity!r}")
        self.capacity = capacity
        self.embedding_dim = embedding_dim
        self._entries: list[MemoryEntry] = []
        self._now = 0

    @property
    def entries(self) -> list[MemoryEntry]:
        return list(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def clear(self) -> None:
        self._entries = []
        self._now = 0

    def find(self, key: Key) -> int | None:
        return next((i for i, e in enumerate(self._entries) if e.key == key), None)

    def write(self, entry: MemoryEntry, keep_scorer: KeepScorer = importance_scorer) -> WriteOutcome:
        self._check_embedding(entry)
        slot = self.find(entry.key)
        if slot is not None:
            self._entries[slot] = entry
            return WriteOutcome(slot, replaced=True)
        if len(self._entries) < self.capacity:
            self._entries.append(entry)
            return WriteOutcome(len(self._entries) - 1)
        scores = np.asarray(keep_scorer([*self._entries, entry]), dtype=np.float64)
        if scores.shape != (self.capacity + 1,):
            raise ValueError(f"keep_scorer returned shape {scores.shape}, expected ({self.capacity + 1},)")
        loser = int(np.argmin(scores))
        if loser == self.capacity:
            return WriteOutcome(None, evicted=entry)
        evicted, self._entries[loser] = self._entries[loser], entry
        return WriteOutcome(loser, evicted=evicted)

    def mark_used(self, slot: int, now: int | None = None) -> None:
        """Count a retrieval of ``slot`` (at time ``now``, for least-recently-used eviction)."""
        if not 0 <= slot < len(self._entries):
            raise IndexError(f"slot {slot} is empty; the bank holds {len(self._entries)} entries")
        self._entries[slot].usage_count += 1
        if now is not None:
            self._entries[slot].last_used = int(now)

    def age(self, now: int) -> None:
        """Set the current time; ages are measured from each entry's timestamp."""
        self._now = int(now)

    def view(self, ages: Sequence[float] | None = None) -> BankView:
        """The bank's arrays; ``ages`` of the entries when their owner counts age otherwise than in steps
        since ``timestamp`` (default: ``now - timestamp``)."""
        n, cap = len(self._entries), self.capacity
        embeddings = np.zeros((cap, self.embedding_dim), dtype=np.float32)
        type_ids = np.zeros(cap, dtype=np.int64)
        age = np.zeros(cap, dtype=np.float32)
        usage = np.zeros(cap, dtype=np.float32)
        for i, e in enumerate(self._entries):
            embeddings[i] = e.embedding
            type_ids[i] = int(e.type)
            age[i] = self._now - e.timestamp if ages is None else ages[i]
            usage[i] = e.usage_count
        return BankView(embeddings, np.arange(cap) < n, type_ids, age, usage)

    def _check_embedding(self, entry: MemoryEntry) -> None:
        if entry.embedding is None or np.shape(entry.embedding) != (self.embedding_dim,):
            raise ValueError(
                f"memory {entry.text!r} has embedding of shape {np.shape(entry.embedding)}; the bank stores "
                f"({self.embedding_dim},) vectors: encode entries before writing them"
            )
