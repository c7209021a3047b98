"""The drawer's decoy seeding: a bank's t=0 memories, the target's drawer among decoys on other drawers, and the
hearsay a household's long-term store hears."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from sb3_memret.tasks.drawer.cabinet import LAYERS, check_layer
from sb3_memret.tasks.drawer.objects import CATALOGUE
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig


def location_memory(entity: str, layer: int, timestamp: int = 0) -> MemoryEntry:
    return MemoryEntry.create(MemoryType.OBJECT_LOCATION, entity, "is_in", f"drawer layer {check_layer(layer)}",
                              timestamp)


def seed_memories(placed: Mapping[str, int], target: str, rng: np.random.Generator,
                  config: SeedingConfig | None = None, facts: bool = True) -> list[MemoryEntry]:
    """The t=0 memories of an episode, in a random order: where each placed object is (the target's
    first), location decoys for absent objects on layers other than the target's, and holding decoys.
    ``facts=False`` leaves out the placed objects' facts: the observed-memory variant writes them from
    what the robot sees.

    Only the target's memory names its layer with its name, so any other pick sends the
    controller to another drawer or to the top one.
    """
    config = config or SeedingConfig()
    config.check_task_objects(CATALOGUE)
    if target not in placed:
        raise ValueError(f"target {target!r} is not among the placed objects {dict(placed)}")
    target_layer = check_layer(placed[target])
    other_layers = [layer for layer in LAYERS if layer != target_layer]
    vocab = sorted(set(config.vocabulary))
    entries = [location_memory(target, target_layer)] if facts else []
    entries += [location_memory(name, layer) for name, layer in placed.items() if name != target and facts]
    for obj in rng.choice(vocab, size=config.location_decoys, replace=False):
        entries.append(location_memory(str(obj), int(rng.choice(other_layers))))
    for obj in rng.choice(vocab, size=config.holding_decoys, replace=False):
        entries.append(MemoryEntry.create(MemoryType.HOLDING, "robot", "holding", str(obj), 0))
    order = rng.permutation(len(entries))
    return [entries[i] for i in order]


def hearsay_memories(n: int, rng: np.random.Generator, timestamp: int,
                     config: SeedingConfig | None = None) -> list[MemoryEntry]:
    """``n`` location facts about things that are none of the task's objects, in random drawers: what a
    household's long-term store also hears, and must learn to let go of."""
    config = config or SeedingConfig()
    config.check_task_objects(CATALOGUE)
    vocab = sorted(set(config.vocabulary))
    return [location_memory(str(obj), int(rng.choice(LAYERS)), timestamp)
            for obj in rng.choice(vocab, size=min(n, len(vocab)), replace=False)]


def is_true_memory(entry: MemoryEntry, target: str, layer: int) -> bool:
    """Whether ``entry`` places ``target`` in ``layer``: the memory the controller needs."""
    return entry.key == (MemoryType.OBJECT_LOCATION, target, "is_in") and entry.value == f"drawer layer {layer}"


__all__ = ["hearsay_memories", "is_true_memory", "location_memory", "seed_memories"]
