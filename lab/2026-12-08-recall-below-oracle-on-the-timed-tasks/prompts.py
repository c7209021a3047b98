"""Replay development seeds of a task through MIKASA's harness as ``benchmark mikasa`` does (a scene built anew) under
one condition, and print the facts of every decision's prompt (the instruction left out) with the step it was made at,
so that the recall condition's prompts can be read beside the oracle's on the seeds where only one of them succeeded.

    .venv/bin/python lab/2026-12-08-recall-below-oracle-on-the-timed-tasks/prompts.py \
        --task TimedTransferEasy-VLA-v0 --condition recall --seeds 5016,5004 --controller learned \
        --learners benchmarks/learners-long-horizon
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sb3_memret.benchmark.runner import Protocol, Unit, _Worker


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--condition", default="recall")
    parser.add_argument("--seeds", required=True, help="comma list of development seeds (5000 + i)")
    parser.add_argument("--controller", default="learned")
    parser.add_argument("--learners", default="benchmarks/learners-long-horizon")
    args = parser.parse_args()
    worker = _Worker(Protocol(episodes=1000, fresh_scenes=True, controller=args.controller), [Path(args.learners)])
    for seed in (int(s) for s in args.seeds.split(",")):
        agent = worker.agent(args.task, args.condition)
        record = worker.play(Unit(args.task, args.condition, seed))
        print(f"{args.task} {args.condition} seed {seed}: success {record.get('success')} steps {record.get('steps')} "
              f"cue {record.get('cue')} {record.get('error', '')}")
        instruction = agent.task.instruction(agent.episode)
        last = None
        for decision, prompt in enumerate(agent.prompts):
            facts = prompt.replace(instruction, "").strip()
            if facts != last:
                print(f"  step {decision * agent.replan_every:4d}: {facts or '(no fact)'}")
                last = facts


if __name__ == "__main__":
    main()
