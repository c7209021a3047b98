"""Executing one action chunk in a task env: the step loop every physics backend and every rollout shares."""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import gymnasium as gym
import numpy as np

from sb3_memret.controllers.base import as_numpy
from sb3_memret.physics.sensor_gate import sensors_pause


@dataclass
class ChunkOutcome:
    """Where executing (a prefix of) an action chunk left the task env."""

    obs: Any
    info: dict
    steps: int  # control steps executed
    terminated: bool
    truncated: bool
    reward: float = 0.0  # the env's reward summed over the executed steps
    succeeded: bool = False  # whether the env reported success at any executed step
    percepts: list[Any] = field(default_factory=list)  # perceive(env, obs) after each step, when asked for


def execute_chunk(env: gym.Env, actions: Sequence[np.ndarray] | np.ndarray,
                  perceive: Callable[[gym.Env, Any], Any] | None = None,
                  perceive_steps: int | None = None) -> ChunkOutcome:
    """Execute ``actions`` in order until the episode ends.

    A controller reads the observation only when it is next called, so an env whose cameras can pause
    (``sensors_pause``: any ManiSkill env) renders only for the one after the last action (the next decision).
    ``perceive(env, obs)`` is called after each of the first ``perceive_steps`` steps (None: every
    step; a writer that must see every step of a cue: those steps are not paused) and its answers
    are the outcome's ``percepts``.
    """
    paused = sensors_pause(env)
    perceived = len(actions) if perceive is None or perceive_steps is None else max(0, perceive_steps)
    obs, info, steps, terminated, truncated = None, {}, 0, False, False
    reward, succeeded, percepts = 0.0, False, []
    for i, action in enumerate(actions):
        looks = perceive is not None and i < perceived
        pause = paused is not None and not looks and i < len(actions) - 1
        with paused() if pause else nullcontext():
            obs, r, term, trunc, info = env.step(action)
        steps += 1
        reward += float(np.sum(as_numpy(r)))
        succeeded = succeeded or bool(np.any(as_numpy(info.get("success", False))))
        if looks:
            percepts.append(perceive(env, obs))
        terminated, truncated = bool(np.any(as_numpy(term))), bool(np.any(as_numpy(trunc)))
        if terminated or truncated:
            break
    return ChunkOutcome(obs, info, steps, terminated, truncated, reward, succeeded, percepts)


__all__ = ["ChunkOutcome", "execute_chunk"]
