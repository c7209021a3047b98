"""Where the decision envs' physics runs, apart from the memory and the controller: task envs that reset and
execute action chunks, in this process, in worker processes, in one batched GPU simulation or in Ray actors
(``backends``, ``ray_actors``), and the step loop of one chunk (``chunks``). ``make_physics`` builds a backend
by name."""

from __future__ import annotations

from typing import Any, Mapping

from sb3_memret.physics.backends import (BACKENDS, BatchedSimPhysics, InProcessPhysics, PhysicsBackend, ProcessPhysics,
                                         ResetRequest, TaskEnvInfo, TaskRunner)
from sb3_memret.tasks import Task


def make_physics(backend: str, num_envs: int, task_kwargs: Mapping[str, Any], max_control_steps: int,
                 ray_address: str | None = None, *, task: Task | str) -> PhysicsBackend:
    """The physics backend ``backend`` names (one of ``BACKENDS``): ``auto`` is in-process for one env and
    worker processes for several (Ray when a ``ray_address`` is given); ``gpu`` one batched GPU simulation;
    ``ray`` Ray actors at ``ray_address`` (None: ``$RAY_ADDRESS`` or a local Ray instance)."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown physics backend {backend!r}; expected one of {list(BACKENDS)}")
    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
    if ray_address is not None and backend == "auto":
        backend = "ray"
    if ray_address is not None and backend != "ray":
        raise ValueError(f"a Ray address ({ray_address!r}) needs the ray backend, not {backend!r}")
    if backend == "auto":
        backend = "inprocess" if num_envs == 1 else "process"
    if backend == "inprocess":
        return InProcessPhysics(num_envs, task_kwargs, max_control_steps, task)
    if backend == "process":
        return ProcessPhysics(num_envs, task_kwargs, max_control_steps, task)
    if backend == "gpu":
        return BatchedSimPhysics(num_envs, task_kwargs, max_control_steps, task)
    from sb3_memret.physics.ray_actors import RayPhysics

    return RayPhysics(num_envs, task_kwargs, max_control_steps, address=ray_address, task=task)


__all__ = ["BACKENDS", "BatchedSimPhysics", "InProcessPhysics", "PhysicsBackend", "ProcessPhysics", "ResetRequest",
           "TaskEnvInfo", "TaskRunner", "make_physics"]
