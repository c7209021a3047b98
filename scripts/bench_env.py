"""Env steps per second of DrawerCubeTakeOut-v1 against ManiSkill's PickCube-v1.

Both run on the CPU with ``pd_ee_delta_pose``, ``obs_mode="state"``, no renderer and the
same seeded random actions, measured in the same process, so their ratio is meaningful on
any machine. Usage: ``python scripts/bench_env.py [--steps N] [--repeats R]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym
import mani_skill.envs  # noqa: F401  (registers PickCube-v1)
import numpy as np
import sapien
from sapien.wrapper.actor_builder import ActorBuilder

import sb3_memret.tasks.drawer.drawer_cube  # noqa: F401  (registers DrawerCubeTakeOut-v1)


def drop_visual_shapes() -> None:
    """Let PickCube-v1 build without a rendering device.

    It adds visual shapes with render materials unconditionally, and constructing a render
    material needs a device. With ``render_backend="none"`` ManiSkill never attaches visuals,
    so dropping them changes nothing that is simulated. DrawerCubeTakeOut-v1 needs no patch.
    """
    sapien.render.RenderMaterial = lambda *args, **kwargs: None
    for name in dir(ActorBuilder):
        if name.startswith("add_") and "visual" in name:
            setattr(ActorBuilder, name, lambda self, *args, **kwargs: self)


def steps_per_second(env_id: str, steps: int, seed: int = 0) -> float:
    env = gym.make(env_id, obs_mode="state", render_backend="none", control_mode="pd_ee_delta_pose")
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, size=(steps, *env.action_space.shape)).astype(np.float32)
    env.reset(seed=seed)
    for a in actions[:20]:  # warm-up
        env.step(a)
    env.reset(seed=seed)
    start = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if bool(terminated) or bool(truncated):
            env.reset()
    elapsed = time.perf_counter() - start
    env.close()
    return steps / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    drop_visual_shapes()
    ours, theirs = [], []
    for r in range(args.repeats):  # interleave, so drift in machine load hits both alike
        ours.append(steps_per_second("DrawerCubeTakeOut-v1", args.steps, seed=r))
        theirs.append(steps_per_second("PickCube-v1", args.steps, seed=r))
    o, t = statistics.median(ours), statistics.median(theirs)
    print(f"control mode pd_ee_delta_pose, obs_mode state, CPU, {args.steps} steps x {args.repeats} (median)")
    print(f"DrawerCubeTakeOut-v1 : {o:8.1f} steps/s")
    print(f"PickCube-v1          : {t:8.1f} steps/s")
    print(f"ratio                : {o / t:8.2f}  (target >= 0.5)")


if __name__ == "__main__":
    main()
