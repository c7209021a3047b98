"""Where a MIKASA-Robo-VLA protocol episode's CPU goes: one control step of MIKASA's harness env (its wrappers, both
128x128 cameras rendered at every step) against the same task stepped with state observations only, in the same
run; and, of the harness step, the share spent reading the cameras' pictures back (``get_picture``).

    python scripts/bench_harness.py [--task RememberColor3-VLA-v0] [--steps 20] [--seed 5000]

The figures are CPU seconds of this process (its threads included), so they hold on a machine whose other cores
are busy; wall time follows them only on an idle machine. Development seeds only.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import gymnasium as gym
import torch


def cpu_per_step(env: gym.Env, steps: int, profile: cProfile.Profile | None = None) -> float:
    """CPU seconds per ``env.step`` of a zero action, over ``steps`` steps (after three to warm up)."""
    action = torch.zeros(env.action_space.shape)
    for _ in range(3):
        env.step(action)
    start = time.process_time()
    if profile is not None:
        profile.enable()
    for _ in range(steps):
        env.step(action)
    if profile is not None:
        profile.disable()
    return (time.process_time() - start) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="RememberColor3-VLA-v0")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--seed", type=int, default=5000, help="a development seed (not MIKASA's 4242424242 + i)")
    args = parser.parse_args()

    from sb3_memret.benchmark import harness

    harness.install_shims()
    state = gym.make(args.task, obs_mode="state", control_mode="pd_ee_delta_pose", sim_backend="cpu")
    state.reset(seed=args.seed)
    state_cpu = cpu_per_step(state, args.steps)
    state.close()

    env = harness.make_env(args.task)
    env.reset(seed=args.seed)
    harness_cpu = cpu_per_step(env, args.steps)
    profile = cProfile.Profile()
    cpu_per_step(env, args.steps, profile)  # a second pass under the profiler, for the shares only
    env.close()
    stats = pstats.Stats(profile)
    picture = sum(entry[3] for key, entry in stats.stats.items() if key[2] == "get_picture")  # cumulative seconds
    profiled = sum(entry[2] for entry in stats.stats.values())  # every function's own time

    print(f"task {args.task}, {args.steps} steps at seed {args.seed}")
    print(f"state observations only: {state_cpu * 1000:7.1f} ms CPU per step")
    print(f"MIKASA's harness (rgb):  {harness_cpu * 1000:7.1f} ms CPU per step  ({harness_cpu / state_cpu:.0f}x)")
    print(f"  of it reading pictures back (get_picture): {picture / profiled:.0%} of the profiled time")


if __name__ == "__main__":
    main()
