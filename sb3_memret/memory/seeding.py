"""Episode seeding's settings: how many decoys a bank starts with, worded about which things, so that retrieval
is a choice. Each task words its decoys (``Task.seed_memories``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

DEFAULT_VOCABULARY: tuple[str, ...] = ("marker", "key", "block", "battery", "mug", "fork", "sponge", "spoon")


@dataclass(frozen=True)
class SeedingConfig:
    """How many decoys of each kind, drawn from which words (never the name of a task object)."""

    location_decoys: int = 5
    holding_decoys: int = 2
    vocabulary: tuple[str, ...] = DEFAULT_VOCABULARY

    def __post_init__(self) -> None:
        need = max(self.location_decoys, self.holding_decoys)
        if min(self.location_decoys, self.holding_decoys) < 0 or len(set(self.vocabulary)) < need:
            raise ValueError(
                f"need at least {need} distinct decoy objects and non-negative decoy counts, got vocabulary "
                f"{self.vocabulary!r} with {self.location_decoys} location and {self.holding_decoys} holding decoys"
            )

    def check_task_objects(self, objects: Iterable[str]) -> None:
        """Refuse a vocabulary that names one of the task's ``objects``: a decoy about it would be a fact."""
        named = sorted(set(self.vocabulary) & set(objects))
        if named:
            raise ValueError(f"the decoy vocabulary must not contain task objects, got {named}; "
                             f"task objects are {sorted(objects)}")


__all__ = ["DEFAULT_VOCABULARY", "SeedingConfig"]
