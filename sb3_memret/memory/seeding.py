"""Episode seeding: the one true cube memory among plausible decoys, so retrieval is a choice."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sb3_memret.envs.cabinet import LAYERS, check_layer
from sb3_memret.memory.schema import MemoryEntry, MemoryType

DEFAULT_VOCABULARY: tuple[str, ...] = ("marker", "key", "block", "battery", "mug", "fork", "sponge", "spoon")


@dataclass(frozen=True)
class SeedingConfig:
    """How many decoys of each kind, drawn from which objects."""

    location_decoys: int = 5
    holding_decoys: int = 2
    vocabulary: tuple[str, ...] = DEFAULT_VOCABULARY

    def __post_init__(self) -> None:
        if "cube" in self.vocabulary:
            raise ValueError("the decoy vocabulary must not contain 'cube', the target object")
        need = max(self.location_decoys, self.holding_decoys)
        if min(self.location_decoys, self.holding_decoys) < 0 or len(set(self.vocabulary)) < need:
            raise ValueError(
                f"need at least {need} distinct decoy objects and non-negative decoy counts, got vocabulary "
                f"{self.vocabulary!r} with {self.location_decoys} location and {self.holding_decoys} holding decoys"
            )


def seed_memories(cube_layer: int, rng: np.random.Generator, config: SeedingConfig | None = None) -> list[MemoryEntry]:
    """The t=0 memories of an episode, in a random order: the true cube location, location
    decoys for other objects on layers other than the cube's, and holding decoys.

    Only the true memory names the cube's layer, so a decoy sends the controller elsewhere.
    """
    config = config or SeedingConfig()
    check_layer(cube_layer)
    other_layers = [layer for layer in LAYERS if layer != cube_layer]
    vocab = sorted(set(config.vocabulary))
    entries = [MemoryEntry.create(MemoryType.OBJECT_LOCATION, "cube", "is_in", f"drawer layer {cube_layer}", 0)]
    for obj in rng.choice(vocab, size=config.location_decoys, replace=False):
        layer = int(rng.choice(other_layers))
        entries.append(MemoryEntry.create(MemoryType.OBJECT_LOCATION, str(obj), "is_in", f"drawer layer {layer}", 0))
    for obj in rng.choice(vocab, size=config.holding_decoys, replace=False):
        entries.append(MemoryEntry.create(MemoryType.HOLDING, "robot", "holding", str(obj), 0))
    order = rng.permutation(len(entries))
    return [entries[i] for i in order]


def is_true_cube_memory(entry: MemoryEntry, cube_layer: int) -> bool:
    return entry.key == (MemoryType.OBJECT_LOCATION, "cube", "is_in") and entry.value == f"drawer layer {cube_layer}"
