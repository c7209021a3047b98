"""How far off is the Rotate writer's start angle? Its reading of the base camera's first frame against the simulator's.

Resets a Rotate task's env at ``--episodes`` development seeds (5000 + i; ``--seed`` for others), reads the peg's
start angle from the reset frame as the task's writer does (``RotateTask.frames``: ``peg_on_table``) and prints the
error against the simulator's start angle (modulo 180 degrees: the peg's halves look alike), in degrees: mean
absolute, 95th percentile, largest, and the mean (a bias). The fact rounds the reading to whole degrees (up to 0.5
more). All four Rotate tasks place the peg alike.

    .venv/bin/python lab/2026-11-27-rotate-reader-error/rotate_reader_error.py [--task RotateLenientPos-VLA-v0] [--episodes 100]
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_memret.tasks.mikasa.core.cue_task import DEV_SEED
from sb3_memret.tasks.mikasa.rotate.task import ROTATE_TASKS, RotateTask


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="RotateLenientPos-VLA-v0", choices=sorted(ROTATE_TASKS))
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=DEV_SEED, help="the first seed")
    args = parser.parse_args()

    task = RotateTask(args.task)
    env = task.make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    errors, unseen = [], []
    try:
        for seed in range(args.seed, args.seed + args.episodes):
            obs, info = env.reset(seed=seed)
            (frame,) = task.frames(env, obs, info, reset=True)
            seen, true = frame.state["seen_start_deg"], frame.state["start_deg"]
            if seen is None:
                unseen.append(seed)
            else:
                errors.append((seen - true + 90.0) % 180.0 - 90.0)
    finally:
        env.close()
    errors = np.asarray(errors)
    print(f"{args.task}: {len(errors)} reset frames at seeds {args.seed}-{args.seed + args.episodes - 1}, "
          f"the peg out of sight in {len(unseen)}" + (f" (seeds {unseen})" if unseen else ""))
    if len(errors):
        print(f"start angle error (degrees): mean absolute {np.abs(errors).mean():.2f}, "
              f"95th percentile {np.percentile(np.abs(errors), 95):.2f}, largest {np.abs(errors).max():.2f}, "
              f"mean {errors.mean():+.2f}")


if __name__ == "__main__":
    main()
