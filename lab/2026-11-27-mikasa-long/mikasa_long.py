"""The scripted expert on MIKASA's -Long cue tasks (600 steps) under the fixed prompts, with the cameras off.

``rollout --condition oracle|none|wrong`` runs no writer and the scripted expert reads no images, yet a task's env
renders its camera at every control step for the writer (about 80 ms a step on this CPU: 50 s a 600-step
episode). This plays the same episodes through the same code (``evaluate_task_condition``: the task's env, its
wrappers, success once, the expert replanning every 4 steps) with the env in ``state_dict`` mode and no per-step
perception, about ten times faster. The writer on these tasks is checked with the cameras on by
``rollout --condition written`` (a few episodes: see ``--written``).

    .venv/bin/python lab/2026-11-27-mikasa-long/mikasa_long.py [--tasks RememberColor3-Long-VLA-v0 ...] [--episodes 20] [--seed 5000]
    .venv/bin/python lab/2026-11-27-mikasa-long/mikasa_long.py --written 3   # the writer's facts in the prompt, cameras on
"""

from __future__ import annotations

import argparse
import time
from typing import Any

LONG_TASKS = tuple(f"RememberColor{n}-Long-VLA-v0" for n in (3, 5, 9)) + tuple(
    f"RememberShape{n}-Long-VLA-v0" for n in (3, 5, 9)) + tuple(
    f"RememberShapeAndColor{n}-Long-VLA-v0" for n in ("3x2", "3x3", "5x3"))


def cameras_off(task: Any) -> Any:
    """``task`` with its env in ``state_dict`` mode and no per-step perception (no writer can read it)."""

    class CamerasOff(type(task)):
        perceives_every_step = False

        def env_kwargs(self, needs_images: bool, render_backend: str) -> dict[str, Any]:
            if needs_images:
                raise ValueError("a controller that reads images needs the cameras")
            return {"obs_mode": "state_dict", "render_backend": render_backend, "robot_uids": "panda"}

    off = CamerasOff.__new__(CamerasOff)
    off.__dict__.update(task.__dict__)
    return off


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(LONG_TASKS))
    parser.add_argument("--conditions", nargs="+", default=["oracle", "none", "wrong"])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=5000, help="first development seed (not MIKASA's 4242424242 + i)")
    parser.add_argument("--written", type=int, default=0, metavar="N",
                        help="instead: N episodes per task of the written condition, cameras on")
    args = parser.parse_args()

    from sb3_memret.evaluation.rollout import evaluate_task_condition
    from sb3_memret.tasks import make_task

    for env_id in args.tasks:
        task = make_task(env_id)
        conditions = ["written"] if args.written else args.conditions
        for condition in conditions:
            t0 = time.perf_counter()
            played = task if args.written else cameras_off(task)
            results = evaluate_task_condition(task.expert(), condition, played, args.written or args.episodes,
                                              seed=args.seed, render_backend="cpu", protocol_seeds=False)
            wins = [r for r in results if r.success]
            steps = sorted(r.steps for r in wins)
            print(f"{env_id} {condition:7s} success {len(wins)}/{len(results)}  steps to success "
                  f"{steps[0] if steps else '-'}..{steps[-1] if steps else '-'}  ({time.perf_counter() - t0:.0f} s)",
                  flush=True)


if __name__ == "__main__":
    main()
