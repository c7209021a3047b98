"""The objects a drawer episode can hide, and the named sets tasks draw them from.

Every object is a box a parallel gripper closes on from above (3.6-5 cm across, so the Panda's
8 cm opening fits and a closed grasp reads wider than 3 cm), with its own size and colour. The
``train`` and ``heldout`` sets share no object, and no object name is a decoy word of the
memory seeding (``sb3_memret.memory.seeding.DEFAULT_VOCABULARY``), so a held-out object's
name never appeared in a training bank.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence


@dataclass(frozen=True)
class ObjectSpec:
    """One graspable object: its name (a lowercase word), box half sizes (m) and RGB colour."""

    name: str
    half_size: tuple[float, float, float]
    color: tuple[float, float, float]


CATALOGUE: Mapping[str, ObjectSpec] = {spec.name: spec for spec in (
    ObjectSpec("cube", (0.02, 0.02, 0.02), (0.9, 0.1, 0.1)),
    ObjectSpec("brick", (0.025, 0.018, 0.017), (0.7, 0.35, 0.2)),
    ObjectSpec("tin", (0.021, 0.021, 0.026), (0.6, 0.6, 0.65)),
    ObjectSpec("box", (0.024, 0.02, 0.02), (0.95, 0.95, 0.9)),
    ObjectSpec("soap", (0.024, 0.018, 0.016), (0.95, 0.6, 0.75)),
    ObjectSpec("eraser", (0.022, 0.018, 0.016), (0.3, 0.4, 0.9)),
    ObjectSpec("dice", (0.018, 0.018, 0.018), (0.2, 0.7, 0.3)),
)}

# Named object sets: ``cube`` is the seed's task; ``train`` and ``heldout`` are disjoint.
OBJECT_SETS: Mapping[str, tuple[str, ...]] = {
    "cube": ("cube",),
    "train": ("cube", "brick", "tin", "box"),
    "heldout": ("soap", "eraser", "dice"),
}


def object_specs(names: Sequence[str]) -> tuple[ObjectSpec, ...]:
    """The catalogue entries of ``names``, refusing unknown or repeated names."""
    names = tuple(names)
    unknown = [n for n in names if n not in CATALOGUE]
    if unknown or not names or len(set(names)) != len(names):
        raise ValueError(f"objects must be distinct names from {sorted(CATALOGUE)}, got {list(names)!r}")
    return tuple(CATALOGUE[n] for n in names)


def object_set(name_or_names: str | Sequence[str]) -> tuple[str, ...]:
    """A named set (``OBJECT_SETS``) or an explicit list of catalogue names, checked."""
    if isinstance(name_or_names, str):
        if name_or_names not in OBJECT_SETS:
            raise ValueError(f"unknown object set {name_or_names!r}; expected one of {sorted(OBJECT_SETS)} "
                             f"or a list of objects from {sorted(CATALOGUE)}")
        return OBJECT_SETS[name_or_names]
    return tuple(spec.name for spec in object_specs(name_or_names))


__all__ = ["CATALOGUE", "OBJECT_SETS", "ObjectSpec", "object_set", "object_specs"]
