"""Run a frozen controller on DrawerCubeTakeOut-v1 under a prompt condition and score it."""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

import gymnasium as gym
import numpy as np

import sb3_memret.envs  # noqa: F401  (registers DrawerCubeTakeOut-v1)
from sb3_memret.controllers.base import FrozenController, as_numpy
from sb3_memret.envs.cabinet import LAYERS, check_layer
from sb3_memret.prompts import CONDITIONS, condition_prompt
from sb3_memret.tasks import Task
from sb3_memret.tasks.base import RENDER_BACKENDS, check_render_backend
from sb3_memret.tasks.drawer import DrawerTask

DEFAULT_REPLAN_EVERY = 8


@dataclass(frozen=True)
class EpisodeResult:
    layer: int
    seed: int
    success: bool
    steps: int  # control steps until success, or the episode limit


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


def make_task_env(obs_mode: str = "state_dict", render_backend: str = "none", **kwargs) -> gym.Env:
    """DrawerCubeTakeOut-v1 as a frozen controller consumes it (CPU physics; cameras only with a
    render backend, ``"cpu"`` being the project's lavapipe)."""
    return DrawerTask().make_env(obs_mode=obs_mode, render_backend=render_backend, **kwargs)


def execute_chunk(env: gym.Env, actions: Sequence[np.ndarray] | np.ndarray,
                  perceive: Callable[[gym.Env, Any], Any] | None = None) -> ChunkOutcome:
    """Execute ``actions`` in order until the episode ends.

    A controller reads the observation only when it is next called, so an env that can pause its
    sensors (``sensors_paused``) renders only for the one after the last action (the next decision).
    ``perceive(env, obs)`` is called after every step (a writer that must see every step: then
    nothing is paused) and its answers are the outcome's ``percepts``.
    """
    paused = getattr(env.unwrapped, "sensors_paused", None)
    obs, info, steps, terminated, truncated = None, {}, 0, False, False
    reward, succeeded, percepts = 0.0, False, []
    for i, action in enumerate(actions):
        pause = paused is not None and perceive is None and i < len(actions) - 1
        with paused() if pause else nullcontext():
            obs, r, term, trunc, info = env.step(action)
        steps += 1
        reward += float(np.sum(as_numpy(r)))
        succeeded = succeeded or bool(np.any(as_numpy(info.get("success", False))))
        if perceive is not None:
            percepts.append(perceive(env, obs))
        terminated, truncated = bool(np.any(as_numpy(term))), bool(np.any(as_numpy(trunc)))
        if terminated or truncated:
            break
    return ChunkOutcome(obs, info, steps, terminated, truncated, reward, succeeded, percepts)



def task_env_kwargs(controller: FrozenController, render_backend: str = "none", task: Task | None = None) -> dict[str, str]:
    """The obs mode and render backend ``controller`` needs on ``task`` (the drawer by default): camera
    images ("rgb") for an image controller, which therefore cannot run without a render backend."""
    check_render_backend(render_backend)
    try:
        return (task or DrawerTask()).env_kwargs(controller.spec.needs_images, render_backend)
    except ValueError as err:
        raise ValueError(f"{type(controller).__name__} {err}") from None


def run_episode(
    env: gym.Env,
    controller: FrozenController,
    prompt: str,
    seed: int,
    layer: int,
    replan_every: int = DEFAULT_REPLAN_EVERY,
    check_prompt: bool = True,
) -> EpisodeResult:
    """One episode: replan every ``replan_every`` steps, execute that prefix of each chunk.

    ``check_prompt=False`` waives the prompt contract (``FrozenController.act``)."""
    if not 1 <= replan_every <= controller.spec.chunk_len:
        raise ValueError(f"replan_every must be in [1, {controller.spec.chunk_len}] (the chunk length), got {replan_every}")
    obs, _ = env.reset(seed=seed, options={"target_layer": check_layer(layer)})
    controller.reset([seed])
    steps = 0
    while True:
        outcome = execute_chunk(env, controller.act(obs, [prompt], check_prompt)[0][:replan_every])
        obs, steps = outcome.obs, steps + outcome.steps
        if outcome.terminated or outcome.truncated:
            return EpisodeResult(layer, seed, bool(outcome.info["success"]), steps)


def evaluate_condition(
    controller: FrozenController,
    condition: str,
    episodes: int,
    layers: Sequence[int] = LAYERS,
    seed: int = 0,
    replan_every: int = DEFAULT_REPLAN_EVERY,
    env: gym.Env | None = None,
    on_episode: Callable[[EpisodeResult], None] | None = None,
    render_backend: str = "none",
) -> list[EpisodeResult]:
    """``episodes`` episodes per layer with the prompt of ``condition``; seeds seed..seed+episodes-1."""
    if condition not in CONDITIONS:
        raise ValueError(f"unknown condition {condition!r}; expected one of {list(CONDITIONS)}")
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    own_env = env is None
    env = make_task_env(**task_env_kwargs(controller, render_backend)) if own_env else env
    controller.check_env(env)
    results = []
    try:
        for layer in layers:
            prompt = condition_prompt(condition, layer)
            for k in range(episodes):
                result = run_episode(env, controller, prompt, seed + k, layer, replan_every)
                results.append(result)
                if on_episode is not None:
                    on_episode(result)
    finally:
        if own_env:
            env.close()
    return results


def summarize(results: Iterable[EpisodeResult]) -> dict:
    """Success rate and median steps-to-success per layer and overall."""
    results = list(results)
    summary: dict = {"success": {}, "median_steps_to_success": {}, "episodes": {}}
    groups = {str(layer): [r for r in results if r.layer == layer] for layer in sorted({r.layer for r in results})}
    groups["overall"] = results
    for key, group in groups.items():
        wins = [r.steps for r in group if r.success]
        summary["episodes"][key] = len(group)
        summary["success"][key] = len(wins) / len(group) if group else float("nan")
        summary["median_steps_to_success"][key] = float(np.median(wins)) if wins else None
    return summary


__all__ = ["ChunkOutcome", "EpisodeResult", "RENDER_BACKENDS", "evaluate_condition", "execute_chunk", "make_task_env",
           "run_episode", "summarize", "task_env_kwargs"]
