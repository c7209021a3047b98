"""The camera BatteriesChecker expert along oracle episodes at development seeds: per call, the cycle's battery and
stage, what it knows of the battery (held, let go and unsettled) against the simulator's, and the episode's outcome.

    .venv/bin/python lab/2026-12-05-batteries-on-the-cameras/cycle_probe.py --task BatteriesCheckerEasy-3-VLA-v0 \
        --seeds 2 --verbose
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.camera_experts import camera_expert


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="BatteriesCheckerEasy-3-VLA-v0")
    parser.add_argument("--seeds", type=int, default=2, help="development seeds FIRST + i")
    parser.add_argument("--first", type=int, default=5000)
    parser.add_argument("--verbose", action="store_true", help="print every call where the stage changes")
    args = parser.parse_args()
    task = make_task(args.task)
    env = task.make_env(obs_mode="rgb")
    n, wins = task.variant.batteries, 0
    for seed in range(args.first, args.first + args.seeds):
        obs, info = env.reset(seed=seed)
        frame = task.frames(env, obs, info, reset=True)[0]
        episode = task.episode(frame)
        controller = camera_expert(task)
        controller.reset([seed])
        last, success, worst = None, False, 0.0
        for call in range(task.max_control_steps // task.replan_every):
            prompt = build_prompt(task.instruction(episode), task.facts_now("oracle", episode, frame, call),
                                  task.template)
            chunk = controller.act(obs, [prompt])[0]
            seen = controller.batteries[0]
            truth = np.stack([as_numpy(b.pose.p).reshape(-1) for b in env.unwrapped.batteries[:n]])
            cycle = controller.cycles[0]
            if seen is not None and seen.unsettled is None:
                worst = max(worst, float(np.linalg.norm(seen.places - truth, axis=1)[:, None].max()))
            state = (cycle.battery, cycle.stage, None if seen is None else (seen.held, seen.unsettled))
            if args.verbose and state != last:
                k = cycle.battery
                err = "" if seen is None or k is None else \
                    f" err {np.round(100 * (seen.places[k] - truth[k]), 1).tolist()} cm"
                print(f"  call {call} step {call * task.replan_every}: battery {k} stage {cycle.stage} "
                      f"held/unsettled {state[2]}{err} checked {frame.state['checked']}")
                last = state
            for action in chunk[: task.replan_every]:
                obs, _, term, trunc, info = env.step(action[None])
                frame = task.frames(env, obs, info)[0]
                success |= frame.success
                if bool(np.asarray(as_numpy(term)).any() or np.asarray(as_numpy(trunc)).any()):
                    break
            if success or bool(np.asarray(as_numpy(trunc)).any()):
                break
        wins += success
        print(f"seed {seed}: success {success} at call {call}, checked {frame.state['checked']}, worst place error "
              f"{100 * worst:.1f} cm")
    print(f"{wins}/{args.seeds}")


if __name__ == "__main__":
    main()
