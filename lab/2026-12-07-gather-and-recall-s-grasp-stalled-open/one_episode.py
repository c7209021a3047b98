"""Play one development seed of one task through MIKASA's harness as ``benchmark mikasa`` does (the oracle condition,
a scene built anew) and print every ``--every``-th decision of the scripted expert: the TCP, the detected cubes, the
fingers' gap and its goal. With fresh scenes an episode no longer depends on those played before it, so one seed is
replayed alone (``harness_replay.py`` of lab/2026-12-05-oracle-misses-on-long-trace-and-gather had to replay its
predecessors; its decision trace is reused here).

    .venv/bin/python lab/2026-12-07-gather-and-recall-s-grasp-stalled-open/one_episode.py \
        --task GatherAndRecall7-VLA-v0 --seed 5013 --every 3
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sb3_memret.benchmark.runner import Protocol, Unit, _Worker

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "2026-12-05-oracle-misses-on-long-trace-and-gather"))
from harness_replay import traced  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="GatherAndRecall7-VLA-v0")
    parser.add_argument("--seed", type=int, default=5013)
    parser.add_argument("--every", type=int, default=3)
    args = parser.parse_args()
    worker = _Worker(Protocol(episodes=1000, fresh_scenes=True), None)  # the seed must be among its development seeds
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
