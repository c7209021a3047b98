"""Run a frozen controller on DrawerCubeTakeOut-v1 under a prompt condition and score it."""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

import gymnasium as gym
import numpy as np

import sb3_memret.envs  # noqa: F401  (registers DrawerCubeTakeOut-v1)
from sb3_memret.controllers.base import RENDER_HINT, FrozenController
from sb3_memret.envs.cabinet import LAYERS, check_layer
from sb3_memret.prompts import CONDITIONS, condition_prompt

ENV_ID = "DrawerCubeTakeOut-v1"
DEFAULT_REPLAN_EVERY = 8
RENDER_BACKENDS = ("none", "cpu", "gpu")


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


def make_task_env(obs_mode: str = "state_dict", render_backend: str = "none", **kwargs) -> gym.Env:
    """DrawerCubeTakeOut-v1 as a frozen controller consumes it (CPU physics; cameras only with a
    render backend, ``"cpu"`` being the project's lavapipe)."""
    if render_backend == "cpu":
        from sb3_memret.rendering import use_cpu_renderer

        use_cpu_renderer()
    return gym.make(ENV_ID, obs_mode=obs_mode, render_backend=render_backend, **kwargs)


def execute_chunk(env: gym.Env, actions: Sequence[np.ndarray] | np.ndarray) -> ChunkOutcome:
    """Execute ``actions`` in order until the episode ends.

    A controller reads the observation only when it is next called, so cameras render only
    for the one after the last action (the next decision), not for every control step.
    """
    paused = env.unwrapped.sensors_paused
    obs, info, steps, terminated, truncated = None, {}, 0, False, False
    for i, action in enumerate(actions):
        with paused() if i < len(actions) - 1 else nullcontext():
            obs, _, term, trunc, info = env.step(action)
        steps += 1
        terminated, truncated = bool(term), bool(trunc)
        if terminated or truncated:
            break
    return ChunkOutcome(obs, info, steps, terminated, truncated)


def task_env_kwargs(controller: FrozenController, render_backend: str = "none") -> dict[str, str]:
    """The obs mode and render backend ``controller`` needs: camera images ("rgb") for an image
    controller, which therefore cannot run without a render backend."""
    if render_backend not in RENDER_BACKENDS:
        raise ValueError(f"unknown render backend {render_backend!r}; expected one of {list(RENDER_BACKENDS)}")
    if not controller.spec.needs_images:
        return {"obs_mode": "state_dict", "render_backend": render_backend}
    if render_backend == "none":
        raise ValueError(f"{type(controller).__name__} needs camera images, so choose a render backend "
                         f"(--render-backend cpu or gpu): {RENDER_HINT}")
    return {"obs_mode": "rgb", "render_backend": render_backend}


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
