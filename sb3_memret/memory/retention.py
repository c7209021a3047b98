"""Fixed eviction rules to compare the learned retention critic with: keep-scores, the lowest is evicted.

- ``fifo``: first in, first out: the entry written longest ago goes (a replaced fact counts as new);
- ``lru``: least recently used: the entry neither written nor retrieved for longest goes;
- ``prior``: the fixed per-type importance (``schema.IMPORTANCE``), what Letta-style memories rank by.

Ties go to the earliest slot (``np.argmin``), as in ``MemoryBank.write``.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from sb3_memret.memory.schema import MemoryEntry

# keep-scores of a bank's entries, from what the entries record (times written and used, type)
RetentionRule = Callable[[Sequence[MemoryEntry]], np.ndarray]


def fifo_scores(entries: Sequence[MemoryEntry]) -> np.ndarray:
    return np.array([e.timestamp for e in entries], dtype=np.float64)


def lru_scores(entries: Sequence[MemoryEntry]) -> np.ndarray:
    return np.array([max(e.timestamp, e.last_used) for e in entries], dtype=np.float64)


def prior_scores(entries: Sequence[MemoryEntry]) -> np.ndarray:
    return np.array([e.importance for e in entries], dtype=np.float64)


FIXED_RULES: dict[str, RetentionRule] = {"fifo": fifo_scores, "lru": lru_scores, "prior": prior_scores}
RETENTION_RULES: tuple[str, ...] = ("learned", *FIXED_RULES)


def check_retention(rule: str) -> str:
    if rule not in RETENTION_RULES:
        raise ValueError(f"unknown retention rule {rule!r}; expected one of {list(RETENTION_RULES)}")
    return rule


__all__ = ["FIXED_RULES", "RETENTION_RULES", "RetentionRule", "check_retention", "fifo_scores", "lru_scores",
           "prior_scores"]
