"""MIKASA-Robo-VLA's own evaluation harness (``mikasa_robo_suite.vla.benchmarking``), made to run on this stack.

Everything an episode does goes through the harness's functions: ``make_benchmark_env`` (``gym.make`` with its
protocol settings, then ``apply_mikasa_vla_wrappers(include_overlays=False)``) and ``run_episode`` (reset at the
episode's seed, a fresh action queue, the policy's ``forward(obs)`` whenever the queue is empty, ``success_once``
latched over the episode). Two parts do not run unchanged on this stack, and are bridged here, narrowly:

- **Imports.** ``apply_wrappers`` imports ``FlattenRGBDObservationWrapper`` from MIKASA's PPO baseline module, which
  needs ``colorama`` and ``tyro`` (dependencies of this package), and must be imported after ManiSkill's envs (else a
  circular import through huggingface_hub).
- **Attribute forwarding.** ``FlattenRGBDObservationWrapper`` reads ``device`` and calls ``update_obs_space`` on a
  ``StateOnlyTensorToDictWrapper`` around the base env, relying on gymnasium < 1.0 forwarding unknown attributes to
  the wrapped env; gymnasium 1.x does not (``AttributeError: ... has no attribute 'device'``). ``install_shims``
  gives that one wrapper class (MIKASA's ``rl`` copy, which the baseline module uses) the forwarding it was written
  against: public names only, and only while the class has no ``__getattr__`` of its own.
- **Rendering.** The harness's env renders both cameras after every control step, and ``run_episode`` hands each
  observation to the policy, which often reads none of them (a chunk's middle steps; a controller that reads no
  images). ``sensor_gate.SensorGate`` lets the agent say which observations it reads: the others carry the last
  images rendered (physics never depends on rendering, so every outcome is the same; ``scripts/bench_benchmark.py``
  measures it).
- **Grasp checks.** MIKASA's envs ask ManiSkill's ``Panda.is_grasping`` of every object they track, in ``evaluate``
  and again in the dense reward: BatteriesChecker 30 times a control step, two thirds of its episode's time on a
  CPU. ``grasp_memo.install_grasp_memo`` reads the fingers and the contacts once per physics step and answers the
  repeats from a memo, in the same operations, so every answer is the same (``scripts/bench_grasp_memo.py``).
- **Renderer.** The harness names no render backend; on a machine without a GPU, ManiSkill falls back to SAPIEN's
  CPU device, which renders with the project's lavapipe once ``use_cpu_renderer`` has pointed Vulkan at it.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

OBS_KEYS = ("rgb", "proprio")  # what a policy may read of the harness's observation (images and proprioception)
FORBIDDEN_KEYS = ("oracle_info", "task_cue")  # in the observation, but reading them disqualifies a run


def _forward_public(self: gym.Wrapper, name: str) -> Any:
    """gymnasium < 1.0's attribute forwarding: a public name this wrapper lacks is the wrapped env's."""
    if name.startswith("_"):
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
    return getattr(self.env, name)


def install_shims(render_backend: str = "cpu") -> None:
    """Make MIKASA's harness importable and runnable here (idempotent); ``render_backend="cpu"`` also points
    SAPIEN at the project's software renderer."""
    if render_backend == "cpu":
        from sb3_memret.common.rendering import use_cpu_renderer

        use_cpu_renderer()
    from sb3_memret.physics.grasp_memo import install_grasp_memo

    import mani_skill.envs  # noqa: F401  (before MIKASA's baseline module: it imports ManiSkill's envs halfway)
    import mikasa_robo_suite.vla.memory_envs  # noqa: F401  (registers the *-VLA-v0 ids)
    from baselines.ppo import ppo_memtasks

    wrapper = ppo_memtasks.StateOnlyTensorToDictWrapper
    if "__getattr__" not in vars(wrapper):
        wrapper.__getattr__ = _forward_public
    install_grasp_memo()


def make_env(env_id: str, sim_backend: str = "cpu", render_backend: str = "cpu", fresh_scenes: bool = False) -> gym.Env:
    """The harness's canonical single env of ``env_id`` (``make_benchmark_env`` with its ``BenchmarkConfig``).

    ``fresh_scenes``: every reset builds the scene anew (ManiSkill's ``reconfiguration_freq`` 1), so an episode does
    not depend on the ones the env played before it. Reusing the scene, as the harness does, carries the physics
    engine's state across resets: TakeItBack's seed 5006 returns 38.17284 after 5005 and 38.17486 alone."""
    install_shims(render_backend)
    from mikasa_robo_suite.vla.benchmarking import BenchmarkConfig, make_benchmark_env

    env = make_benchmark_env(env_id, BenchmarkConfig(sim_backend=sim_backend))
    if fresh_scenes:
        env.unwrapped.reconfiguration_freq = 1
        env.unwrapped._reconfig_counter = 0  # ManiSkill's own countdown: 0 rebuilds at the next reset
    return env


def play_episode(env: gym.Env, policy: Any, seed: int) -> Any:
    """One episode at ``seed`` by the harness's ``run_episode``: its ``EpisodeResult`` (success_once, return,
    steps, seed)."""
    from mikasa_robo_suite.vla.benchmarking import run_episode

    result, _ = run_episode(env, policy, int(seed))
    return result


__all__ = ["FORBIDDEN_KEYS", "OBS_KEYS", "install_shims", "make_env", "play_episode"]
