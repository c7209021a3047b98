"""Episode seeding's settings: how many decoys a bank starts with, worded about which things, so that retrieval
is a choice. Each task words its decoys (``Task.seed_memories``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

DEFAULT_VOCABULARY: tuple[str, ...] = ("marker", "key", "block", "battery", "mug", "fork", "sponge", "spoon")


@dataclass(frozen=True)
class SeedingConfig:
    """How many decoys of each kind, drawn from which words (never the name of a task object); with
    ``event_every > 0``, also one event decoy every that many control steps of an episode (``Task.event_decoy``:
    things seen in passing, written while the task goes on, so that what the cue established competes for room
    with a stream of what only mattered at the moment)."""

    location_decoys: int = 5
    holding_decoys: int = 2
    vocabulary: tuple[str, ...] = DEFAULT_VOCABULARY
    event_every: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.event_every, bool) or not isinstance(self.event_every, int) or self.event_every < 0:
            raise ValueError(f"event_every must be an integer >= 0 (control steps between event decoys; 0: none), "
                             f"got {self.event_every!r}")
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
