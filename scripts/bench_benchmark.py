"""Throughput of ``sb3-memret benchmark mikasa``: protocol episodes through MIKASA's harness with 1 worker
against N worker processes, in the same run, at development seeds.

    python scripts/bench_benchmark.py [--task RememberColor3-VLA-v0] [--controller scripted]
        [--condition oracle] [--episodes 8] [--workers 1 2]

Each worker count plays the same ``--episodes`` episodes (seeds 5000 + i) end to end, start-up included, as a user
waits for them (``play_units``: the worker processes are spawned, build the harness env and the agent, then
play). It prints episodes/s, control steps/s and decisions/s (controller calls: one per ``replan_every`` steps)
per worker count, and each count's ratio to one worker. Each outcome is checked to be the same across counts: a
worker count changes how fast the table plays, never what it says.
"""

from __future__ import annotations

import argparse
import math
import time

from sb3_memret.benchmark.manifest import DEV_SEED
from sb3_memret.benchmark.runner import Protocol, Unit, play_units
from sb3_memret.tasks import make_task


def play(task: str, controller: str, condition: str, episodes: int, workers: int) -> tuple[float, list[dict]]:
    """Seconds to play ``episodes`` development-seed episodes with ``workers`` workers, and their records."""
    units = [Unit(task, condition, DEV_SEED + i) for i in range(episodes)]
    protocol = Protocol(seed_set="dev", episodes=episodes, controller=controller)
    start = time.perf_counter()
    records = sorted(play_units(units, protocol, None, workers), key=lambda record: record["seed"])
    return time.perf_counter() - start, records


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="RememberColor3-VLA-v0")
    parser.add_argument("--controller", default="scripted")
    parser.add_argument("--condition", default="oracle", choices=["none", "oracle", "wrong", "written"])
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()

    replan_every = make_task(args.task).replan_every
    print(f"{args.task}, {args.controller} controller, {args.condition}, {args.episodes} episodes at seeds "
          f"{DEV_SEED}..{DEV_SEED + args.episodes - 1}, replanning every {replan_every} steps")
    print("| workers | seconds | episodes/s | steps/s | decisions/s | vs 1 worker | success |")
    print("|---|---|---|---|---|---|---|")
    base, outcomes = None, None
    for workers in args.workers:
        seconds, records = play(args.task, args.controller, args.condition, args.episodes, workers)
        errors = [record["error"] for record in records if "error" in record]
        if errors:
            raise SystemExit(f"{len(errors)} episodes failed with {workers} workers: {errors[0]}")
        steps = sum(record["steps"] for record in records)
        decisions = sum(math.ceil(record["steps"] / replan_every) for record in records)
        outcome = [(record["success"], record["steps"]) for record in records]
        if outcomes is not None and outcome != outcomes:
            raise SystemExit(f"{workers} workers played other outcomes than {args.workers[0]}: {outcome} vs {outcomes}")
        outcomes, rate = outcome, args.episodes / seconds
        base = base or rate
        print(f"| {workers} | {seconds:.1f} | {rate:.3f} | {steps / seconds:.1f} | {decisions / seconds:.2f} | "
              f"{rate / base:.2f}x | {sum(s for s, _ in outcome)}/{args.episodes} |")


if __name__ == "__main__":
    main()
