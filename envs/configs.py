"""The decision env's settings in three frozen configs, each checked when it is made: what every env's memory
holds and forgets (``MemoryConfig``), how a retrieval decision meets the controller and the reward
(``DecisionConfig``), and where the task envs run (``PhysicsConfig``). The task owns its own options (the drawer:
objects, households). A run saves them as its config's flat ``env_kwargs`` (rl-zoo's form), which
``split_env_kwargs`` reads back into the task and the three configs."""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, Mapping

from sb3_memret.memory.retention import check_retention
from sb3_memret.memory.schema import check_age_unit
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.memory.stores import StoreSpec, age_units, check_stores
from sb3_memret.physics import BACKENDS
from sb3_memret.tasks import Task, make_task, task_in
from sb3_memret.tasks.base import check_render_backend


MODES = ("recall", "oracle", "none")
# where the placed objects' facts come from: the episode's placement (the seed's), or what the robot saw
MEMORY_SOURCES = ("seeded", "observed")


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; expected one of {list(MODES)}")
    return mode


def check_memory_source(source: str) -> str:
    if source not in MEMORY_SOURCES:
        raise ValueError(f"unknown memory source {source!r}; expected one of {list(MEMORY_SOURCES)}")
    return source


@dataclass(frozen=True)
class MemoryConfig:
    """Each env's memory: its stores (``stores``, a multi-timescale memory: ``sb3_memret.memory.stores``), or in
    short ``capacity`` per-episode slots after ``long_term_capacity`` slots that outlive episodes (a household's;
    written from what the robot saw, so ``source="observed"``); where the facts come from (``source``: the
    episode's placement, or what the robot saw), what evicts (``retention``: the learned critic or a fixed rule; a
    store may name its own), the unit of a memory's age (``age_unit``; a store of ``stores`` names its own) and the
    decoys each bank starts with (``seeding``)."""

    capacity: int = 6
    long_term_capacity: int = 0
    source: str = "seeded"
    retention: str = "learned"
    age_unit: str = "steps"
    seeding: SeedingConfig = field(default_factory=SeedingConfig)
    stores: tuple[StoreSpec, ...] = ()

    def __post_init__(self) -> None:
        if self.capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {self.capacity}")
        if self.long_term_capacity < 0:
            raise ValueError(f"long_term_capacity must be >= 0, got {self.long_term_capacity}")
        check_memory_source(self.source)
        check_retention(self.retention)
        check_age_unit(self.age_unit)
        if self.stores:
            object.__setattr__(self, "stores", check_stores(self.stores))
            if self.long_term_capacity:
                raise ValueError("give either stores or long_term_capacity: a lasting store in stores is the "
                                 "long-term store")
        if self.household and self.source != "observed":
            raise ValueError("a long-term store is written from what the robot sees (a lasting store): use "
                             "memory_source='observed'")

    @property
    def store_specs(self) -> tuple[StoreSpec, ...]:
        """The stores in slot order: ``stores``, else the long-term store (if any) and the episode's."""
        if self.stores:
            return self.stores
        episode = StoreSpec("episode", self.capacity, self.age_unit)
        if not self.long_term_capacity:
            return (episode,)
        return StoreSpec("lasting", self.long_term_capacity, self.age_unit), episode

    @property
    def slots(self) -> int:
        """The slots the retriever chooses among: every store's, in slot order."""
        return sum(s.capacity for s in self.store_specs)

    @property
    def household(self) -> bool:
        """Whether a store outlives episodes (its env is a household whose episodes are its tasks)."""
        return any(s.survives_episodes for s in self.store_specs)

    @property
    def age_units(self) -> str | dict[str, str]:
        """The unit the critic reads each store's ages in (one, or one per timescale: ``stores.age_units``)."""
        return age_units(self.store_specs)


@dataclass(frozen=True)
class DecisionConfig:
    """One retrieval decision: the ``mode`` (recall; oracle and none for baselines), ``k`` slots retrieved, the
    controller replanning every ``replan_every`` control steps (None: the task's) ``replans_per_decision`` times
    per decision, a decision ending early at a written fact (``retrieve_on_write``); its reward discounted by
    ``gamma`` with ``success_bonus`` on success; ``tasks_per_episode`` tasks per learning episode; whether the
    observation carries the shaping potential (``observe_potential``); episodes cut at ``max_control_steps``
    (None: the task's)."""

    mode: str = "recall"
    k: int = 1
    replan_every: int | None = None
    replans_per_decision: int = 1
    retrieve_on_write: bool = False
    gamma: float = 0.97
    success_bonus: float = 0.0
    tasks_per_episode: int = 1
    observe_potential: bool = False
    max_control_steps: int | None = None

    def __post_init__(self) -> None:
        check_mode(self.mode)
        for name in ("k", "replans_per_decision", "tasks_per_episode"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("replan_every", "max_control_steps"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1 or None (the task's), got {getattr(self, name)}")
        if not 0.0 < self.gamma <= 1.0:
            raise ValueError(f"gamma must be in (0, 1], got {self.gamma}")
        if self.success_bonus < 0:
            raise ValueError(f"success_bonus must be >= 0, got {self.success_bonus}")


@dataclass(frozen=True)
class PhysicsConfig:
    """Where the task envs run (``backend``: ``sb3_memret.physics.BACKENDS``; ``ray_address``: a Ray cluster),
    what renders their cameras (``render_backend``) and any further keyword arguments for the task's env."""

    backend: str = "auto"
    ray_address: str | None = None
    render_backend: str = "none"
    task_kwargs: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f"unknown physics backend {self.backend!r}; expected one of {list(BACKENDS)}")
        if self.ray_address is not None and self.backend not in ("auto", "ray"):
            raise ValueError(f"a Ray address ({self.ray_address!r}) needs the ray backend, not {self.backend!r}")
        check_render_backend(self.render_backend)


def _fields(cls: type) -> set[str]:
    return {f.name for f in fields(cls)}


def with_retention(env_kwargs: Mapping[str, Any], rule: str) -> dict[str, Any]:
    """``env_kwargs`` evicting by ``rule`` everywhere: the memory's rule and every store's own."""
    kwargs = {**env_kwargs, "retention": check_retention(rule)}
    if kwargs.get("stores"):
        kwargs["stores"] = [{**(s.to_mapping() if isinstance(s, StoreSpec) else dict(s)), "retention": rule}
                            for s in kwargs["stores"]]
    return kwargs


def split_env_kwargs(env_kwargs: Mapping[str, Any]) -> tuple[Task, dict[str, Any], MemoryConfig, DecisionConfig,
                                                               PhysicsConfig]:
    """A run's flat ``env_kwargs`` as the task (with its own options), the rest (``controller``, ``encoder``) and
    the three configs. ``memory_source`` is ``MemoryConfig.source``; ``location_decoys``, ``holding_decoys`` and
    ``event_every`` override the ``seeding`` config's counts; a key no config or task takes is refused, naming it."""
    kwargs = dict(env_kwargs)
    memory_keys, decision_keys, physics_keys = _fields(MemoryConfig), _fields(DecisionConfig), _fields(PhysicsConfig)
    if "memory_source" in kwargs:
        kwargs["source"] = kwargs.pop("memory_source")
    decoys = {k: v for k in ("location_decoys", "holding_decoys", "event_every")
              if (v := kwargs.pop(k, None)) is not None}
    if kwargs.get("stores"):
        clash = sorted({"capacity", "long_term_capacity", "age_unit"} & set(kwargs))
        if clash:
            raise ValueError(f"stores give each store its capacity and age unit: drop {clash}, or drop stores")
        kwargs["stores"] = check_stores(kwargs["stores"])
    seeding = replace(kwargs.pop("seeding", None) or SeedingConfig(), **decoys)
    memory = MemoryConfig(seeding=seeding, **{k: kwargs.pop(k) for k in list(kwargs) if k in memory_keys - {"seeding"}})
    decisions = DecisionConfig(**{k: kwargs.pop(k) for k in list(kwargs) if k in decision_keys})
    physics = PhysicsConfig(**{k: kwargs.pop(k) for k in list(kwargs) if k in physics_keys})
    task = make_task(task_in(kwargs))
    kwargs.pop("task", None)
    rest = {k: kwargs.pop(k) for k in ("controller", "encoder") if k in kwargs}
    task = task.with_options(**kwargs)  # what is left is the task's own, or refused by it
    return task, rest, memory, decisions, physics


__all__ = ["DecisionConfig", "MEMORY_SOURCES", "MODES", "MemoryConfig", "PhysicsConfig", "check_memory_source", "check_mode",
           "split_env_kwargs", "with_retention"]
