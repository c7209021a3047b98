"""Where the base camera places RememberColor's cubes, against the simulator: each development seed's first frame
with more than the cue's one cube out (zero actions, the arm at its initial pose), the colours placed and each one's
error in centimetres.

    .venv/bin/python lab/2026-12-05-five-more-families-on-the-cameras/layout_probe.py --task RememberColor9-VLA-v0
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_memret.controllers.base import as_numpy
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.core.layout_perception import CubeLayout


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="RememberColor9-VLA-v0")
    parser.add_argument("--seeds", type=int, default=10, help="development seeds 5000 + i")
    parser.add_argument("--steps", type=int, default=25, help="control steps to look for the cubes in")
    args = parser.parse_args()
    task = make_task(args.task)
    env = task.make_env(obs_mode="rgb")
    worst = 0.0
    for seed in range(5000, 5000 + args.seeds):
        obs, _ = env.reset(seed=seed)
        layout = CubeLayout(1, task.n_words)
        for step in range(args.steps):
            layout.see(obs["sensor_data"]["base_camera"]["rgb"])
            if layout.complete:
                break
            obs, *_ = env.step(np.zeros(env.action_space.shape))
        truth = {task.words[i]: as_numpy(cube.pose.p).reshape(-1)[:2] for i, cube in env.unwrapped.cubes.items()}
        errors = {c: round(100 * float(np.linalg.norm(p - truth[c])), 2) for c, p in layout.places.items()}
        worst = max([worst, *errors.values()])
        print(f"seed {seed} step {step}: placed {len(layout.places)}/{task.n_words}, error (cm) {errors}", flush=True)
    print(f"worst error {worst:.2f} cm")
    env.close()


if __name__ == "__main__":
    main()
