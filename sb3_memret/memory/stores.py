"""The stores of a multi-timescale memory: each holds the facts of one timescale, with its own capacity, age unit
and eviction rule, so that a fact persists at the scale it matters and a flood at one scale cannot flush another.

- ``now``: what holds at the moment (the grasp, the current sub-goal, the last event); emptied at each episode;
- ``episode``: what this episode established (the cue, the sequence, the count); emptied at each episode;
- ``lasting``: what holds across episodes (a household's habits, where things were seen); kept across resets.

A task says which timescale each fact it writes belongs to (``Task.timescale``). A memory need not have a store
per timescale: a fact whose timescale has none goes to the next longer-lived store there is, else the next
shorter one, so one store (one bank) takes every fact, and ``lasting`` plus ``episode`` is the household's layout.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Iterable, Mapping

from sb3_memret.memory.retention import check_retention
from sb3_memret.memory.schema import check_age_unit

TIMESCALES: tuple[str, ...] = ("now", "episode", "lasting")  # shortest-lived first
LASTING = "lasting"


def check_timescale(timescale: str) -> str:
    if timescale not in TIMESCALES:
        raise ValueError(f"unknown timescale {timescale!r}; expected one of {list(TIMESCALES)}")
    return timescale


@dataclass(frozen=True)
class StoreSpec:
    """One store: the ``timescale`` of the facts it holds, at most ``capacity`` of them, their ages counted in
    ``age_unit`` (control steps, or a household's tasks) and evicted by ``retention`` (None: the memory's rule)."""

    timescale: str
    capacity: int
    age_unit: str = "steps"
    retention: str | None = None

    def __post_init__(self) -> None:
        check_timescale(self.timescale)
        if isinstance(self.capacity, bool) or not isinstance(self.capacity, int) or self.capacity < 1:
            raise ValueError(f"the {self.timescale} store's capacity must be an integer >= 1, got {self.capacity!r}")
        check_age_unit(self.age_unit)
        if self.retention is not None:
            check_retention(self.retention)

    @property
    def survives_episodes(self) -> bool:
        return self.timescale == LASTING

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | "StoreSpec") -> "StoreSpec":
        """A store from a config's mapping (``{timescale: episode, capacity: 8}``); an unknown key is refused."""
        if isinstance(values, StoreSpec):
            return values
        if not isinstance(values, Mapping):
            raise ValueError(f"a store is a mapping with timescale and capacity (and optionally age_unit, retention), "
                             f"got {values!r}")
        known = {"timescale", "capacity", "age_unit", "retention"}
        unknown = sorted(set(values) - known)
        missing = sorted({"timescale", "capacity"} - set(values))
        if unknown or missing:
            raise ValueError(f"store {dict(values)!r}: unknown keys {unknown} / missing keys {missing}; a store takes "
                             f"{sorted(known)} (timescale and capacity required)")
        return cls(**values)

    def to_mapping(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}


def check_stores(stores: Iterable[Mapping[str, Any] | StoreSpec]) -> tuple[StoreSpec, ...]:
    """``stores`` as StoreSpecs, at least one and at most one per timescale, in the order given (the slot order)."""
    specs = tuple(StoreSpec.from_mapping(s) for s in stores)
    if not specs:
        raise ValueError("a memory needs at least one store")
    timescales = [s.timescale for s in specs]
    repeated = sorted({t for t in timescales if timescales.count(t) > 1})
    if repeated:
        raise ValueError(f"one store per timescale, but {repeated} appear more than once in {timescales}")
    return specs


def store_index(timescale: str, stores: tuple[StoreSpec, ...]) -> int:
    """The store a fact of ``timescale`` goes to: its own; else the nearest longer-lived store; else the nearest
    shorter-lived one."""
    rank = TIMESCALES.index(check_timescale(timescale))
    by_rank = {TIMESCALES.index(s.timescale): i for i, s in enumerate(stores)}
    longer = [r for r in by_rank if r >= rank]
    return by_rank[min(longer)] if longer else by_rank[max(by_rank)]


def timescale_id(timescale: str) -> int:
    """The timescale's index in ``TIMESCALES``: what the critic's store embedding reads."""
    return TIMESCALES.index(check_timescale(timescale))


def age_units(stores: tuple[StoreSpec, ...]) -> str | dict[str, str]:
    """The unit of each store's ages: one unit when every store counts in it (what one store's critic reads), else
    a mapping from timescale to unit."""
    units = {s.timescale: s.age_unit for s in stores}
    return next(iter(units.values())) if len(set(units.values())) == 1 else units


def units_per_timescale(age_unit: str | Mapping[str, str], timescales: Iterable[str]) -> dict[str, str]:
    """``age_unit`` (one unit for all, or one per timescale) spelled out for each of ``timescales``; a timescale the
    mapping leaves out is refused."""
    timescales = list(timescales)
    if isinstance(age_unit, str):
        return {t: check_age_unit(age_unit) for t in timescales}
    missing = [t for t in timescales if t not in age_unit]
    if missing:
        raise ValueError(f"age units {dict(age_unit)!r} name no unit for the {missing} store(s)")
    return {t: check_age_unit(age_unit[t]) for t in timescales}


__all__ = ["LASTING", "StoreSpec", "TIMESCALES", "age_units", "check_stores", "check_timescale", "store_index",
           "timescale_id", "units_per_timescale"]
