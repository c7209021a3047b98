"""Play one development seed of a GatherAndRecall task through MIKASA's harness as ``benchmark mikasa`` does (the
oracle condition, a scene built anew) and print every ``--every``-th decision of its expert: the TCP, the cubes as
the expert sees them (the simulated detector's, or the cameras' readings with ``--controller scripted-camera``), the
fingers' gap and the goal. With fresh scenes an episode no longer depends on those played before it, so one seed is
replayed alone.

    .venv/bin/python lab/2026-12-07-gather-and-recall-s-grasp-stalled-open/one_episode.py \
        --task GatherAndRecall7-VLA-v0 --seed 5013 --every 3
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_memret.benchmark.runner import Protocol, Unit, _Worker


def traced(expert, log: list[str]) -> None:
    """Wrap the expert's ``_goal`` so that every decision appends what it saw and chose to ``log``."""
    goal = expert._goal

    def logged(pos, cubes, gap, *rest):
        chosen = goal(pos, cubes, gap, *rest)
        log.append(f"tcp {np.round(pos, 3).tolist()} cubes {np.round(cubes, 3).tolist()} gap {gap:.3f} "
                   f"goal {(chosen.mode, np.round(np.asarray(chosen.point), 3).tolist())}")
        return chosen
    expert._goal = logged


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="GatherAndRecall7-VLA-v0")
    parser.add_argument("--seed", type=int, default=5013)
    parser.add_argument("--every", type=int, default=3)
    parser.add_argument("--controller", default="scripted", help="scripted, or scripted-camera (on the cameras' readings)")
    args = parser.parse_args()
    # episodes: the seed must be among the protocol's development seeds
    worker = _Worker(Protocol(episodes=1000, fresh_scenes=True, controller=args.controller), None)
    agent = worker.agent(args.task, "oracle")
    log: list[str] = []
    traced(agent.controller, log)
    record = worker.play(Unit(args.task, "oracle", args.seed))
    print(args.seed, "success", record.get("success"), "steps", record.get("steps"), record.get("error", ""))
    for i, line in enumerate(log):
        if i % args.every == 0:
            print(f"  step {i * agent.replan_every}: {line}")


if __name__ == "__main__":
    main()
