"""What the grasp memo (``sb3_memret.physics.grasp_memo``) saves: the same benchmark episodes through MIKASA's harness
with ManiSkill's own ``Panda.is_grasping`` and with the memo, each in a fresh process, at development seeds.

    python scripts/bench_grasp_memo.py [--task BatteriesCheckerEasy-3-VLA-v0] [--condition none] [--episodes 2]

It prints each one's seconds, control steps a second and the time spent in grasp checks, the memo's ratio to
ManiSkill's, and checks that every episode's outcome (success, return, steps) is the same both ways.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time


def play(task: str, condition: str, episodes: int, memo: bool) -> dict:
    """Play the episodes in this process; ManiSkill's own grasp check unless ``memo``."""
    import torch
    from mani_skill.agents.robots.panda.panda import Panda

    from sb3_memret.benchmark.harness import install_shims
    from sb3_memret.benchmark.runner import Protocol, Unit, _Worker

    torch.set_num_threads(1)  # as every benchmark worker
    install_shims()
    check = Panda.is_grasping if memo else Panda.is_grasping.__wrapped__
    spent = {"seconds": 0.0, "calls": 0}

    def timed(self, *args, **kwargs):
        start = time.perf_counter()
        answer = check(self, *args, **kwargs)
        spent["seconds"] += time.perf_counter() - start
        spent["calls"] += 1
        return answer

    Panda.is_grasping = timed
    protocol = Protocol(seed_set="dev", episodes=episodes, controller="scripted")
    worker = _Worker(protocol, None)
    worker.agent(task, condition)  # the env and agent built before the clock starts
    start = time.perf_counter()
    outcomes = [worker.play(Unit(task, condition, seed)) for seed in protocol.seeds()]
    seconds = time.perf_counter() - start
    errors = [o["error"] for o in outcomes if "error" in o]
    if errors:
        raise SystemExit(f"an episode failed: {errors[0]}")
    return {"seconds": seconds, "steps": sum(o["steps"] for o in outcomes), "grasp_seconds": spent["seconds"],
            "grasp_calls": spent["calls"],
            "outcomes": [(o["seed"], o["success"], o["return"], o["steps"]) for o in outcomes]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="BatteriesCheckerEasy-3-VLA-v0")
    parser.add_argument("--condition", default="none", help="none plays every episode to its step limit")
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--mode", choices=["maniskill", "memo"], help=argparse.SUPPRESS)  # one side, in a child
    args = parser.parse_args()
    if args.mode is not None:
        print(json.dumps(play(args.task, args.condition, args.episodes, args.mode == "memo")))
        return
    runs = {}
    for mode in ("maniskill", "memo"):
        child = subprocess.run([sys.executable, __file__, "--task", args.task, "--condition", args.condition,
                                "--episodes", str(args.episodes), "--mode", mode],
                               capture_output=True, text=True, check=True)
        runs[mode] = json.loads(child.stdout.strip().splitlines()[-1])
    print(f"{args.task}, {args.condition}, {args.episodes} episodes at development seeds, one torch thread")
    print("| grasp check | seconds | control steps/s | in grasp checks | calls | ratio |")
    print("|---|---|---|---|---|---|")
    base = runs["maniskill"]["seconds"]
    for mode, run in runs.items():
        print(f"| {mode} | {run['seconds']:.1f} | {run['steps'] / run['seconds']:.1f} | {run['grasp_seconds']:.1f} s "
              f"| {run['grasp_calls']} | {base / run['seconds']:.2f}x |")
    same = runs["maniskill"]["outcomes"] == runs["memo"]["outcomes"]
    print(f"outcomes (success, return, steps) the same both ways: {same}")
    if not same:
        raise SystemExit(f"outcomes differ: {runs['maniskill']['outcomes']} against {runs['memo']['outcomes']}")


if __name__ == "__main__":
    main()
