"""How a frozen controller's success depends on which memory its prompt carries at each decision.

The memory learner changes the prompt at every decision; a controller trained on prompts that stay the
same through an episode may answer a switch differently from one that re-reads its prompt (the scripted
expert). This plays a task's episodes under prompt *schedules* and prints success per schedule:

* ``oracle`` / ``decoy``: the true fact, or one decoy (drawn as the recall env draws them), throughout;
* ``decoy-then-oracle`` / ``oracle-then-decoy``: one, then the other from decision ``--switch`` on;
* ``uniform``: a memory drawn uniformly from the bank (the true fact and the decoys) at every decision,
  which is what a retriever at maximum entropy plays. For it the script also prints success by how many
  of the decisions from ``--switch`` on carried the true fact: the signal PPO has to find.

Episodes play the task's development seeds; ``--seeds protocol`` plays its test set, for a final figure only.

    python scripts/prompt_schedules.py --task TakeItBack-VLA-v0 --controller learned --episodes 30
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict
from typing import Sequence

import numpy as np

from sb3_memret.cli.options import SEED_SET_KINDS
from sb3_memret.common.seeds import held_out_seeds
from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers.base import FrozenController
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.evaluation.rollout import EpisodeResult, FactSchedule, play_task_episodes
from sb3_memret.tasks import Task, make_task
from sb3_memret.tasks.base import EnvFrame, Episode

SCHEDULES = ("oracle", "decoy", "decoy-then-oracle", "oracle-then-decoy", "uniform")


def fact_at(schedule: str, decision: int, switch: int, true_fact: str, decoys: list[str],
            rng: np.random.Generator) -> str:
    """The fact the prompt carries at ``decision`` under ``schedule``."""
    if schedule == "oracle":
        return true_fact
    if schedule == "decoy":
        return decoys[0]
    if schedule == "decoy-then-oracle":
        return true_fact if decision >= switch else decoys[0]
    if schedule == "oracle-then-decoy":
        return decoys[0] if decision >= switch else true_fact
    if schedule == "uniform":
        bank = [true_fact, *decoys]
        return bank[int(rng.integers(len(bank)))]
    raise ValueError(f"unknown schedule {schedule!r}; expected one of {list(SCHEDULES)}")


class ScheduledFacts(FactSchedule):
    """``schedule``'s fact at each decision of an episode, recording whether each one was the true fact."""

    def __init__(self, task: Task, schedule: str, switch: int, seeding: SeedingConfig, rng: np.random.Generator):
        self.task, self.schedule, self.switch, self.seeding, self.rng = task, schedule, switch, seeding, rng
        self.true_fact, self.bank, self.used = "", [], []

    def start(self, frame: EnvFrame, episode: Episode) -> None:
        self.true_fact, = self.task.oracle_facts(episode)
        self.bank = [m.text for m in self.task.seed_memories(frame, episode, self.rng, self.seeding)]
        self.used = []

    def facts(self, decision: int) -> list[str]:
        fact = fact_at(self.schedule, decision, self.switch, self.true_fact, self.bank, self.rng)
        self.used.append(fact == self.true_fact)
        return [fact]


def play(task: Task, controller: FrozenController, schedules: Sequence[str], episodes: int, switch: int,
         replan_every: int = 4, decoys: int = 5, seed: int = 0, verbose: bool = False,
         held_out: str = "development") -> list[dict]:
    """Play ``episodes`` episodes of ``task`` (its ``held_out`` seeds: development, or "evaluation", the protocol's
    test set, for a final figure only; 0, 1, ... for a task without them) under each schedule; one record per
    episode: its schedule, seed, group, first decoy, whether each decision carried the true fact, and success."""
    for s in schedules:
        if s not in SCHEDULES:
            raise ValueError(f"unknown schedule {s!r}; expected some of {list(SCHEDULES)}")
    seeds = held_out_seeds(task, held_out, episodes) or list(range(episodes))
    records: list[dict] = []
    start = time.perf_counter()
    for schedule in schedules:
        seeding, rng = SeedingConfig(location_decoys=decoys), np.random.default_rng(seed)
        facts = ScheduledFacts(task, schedule, switch, seeding, rng)

        def record(result: EpisodeResult) -> None:
            records.append(dict(schedule=schedule, seed=int(result.seed), group=str(result.group),
                                decoy=facts.bank[0], true=list(facts.used), success=bool(result.success)))

        play_task_episodes(controller, task, seeds, facts, replan_every, on_episode=record)
        if verbose:
            wins = [r["success"] for r in records if r["schedule"] == schedule]
            print(f"{schedule:>18}: {100 * np.mean(wins):5.1f}% of {len(wins)}  "
                  f"({time.perf_counter() - start:.0f} s)", flush=True)
    return records


def uniform_breakdown(records: Sequence[dict], switch: int) -> list[str]:
    """Lines of the uniform schedule's success by the true fact's count from ``switch`` on, then by decision."""
    uniform = [r for r in records if r["schedule"] == "uniform"]
    if not uniform:
        return []
    by_count: dict[int, list[bool]] = defaultdict(list)
    for r in uniform:
        by_count[int(sum(r["true"][switch:]))].append(r["success"])
    lines = [f"uniform, by the true fact's count in decisions {switch}..:"]
    lines += [f"  {count:2d}: {100 * np.mean(by_count[count]):5.1f}% of {len(by_count[count])}"
              for count in sorted(by_count)]
    wins = np.array([r["success"] for r in uniform], float)
    for d in range(max(len(r["true"]) for r in uniform)):
        hit = np.array([len(r["true"]) > d and r["true"][d] for r in uniform])
        if hit.any() and (~hit).any():
            lines.append(f"  decision {d:2d}: true {100 * wins[hit].mean():5.1f}% ({hit.sum()}), "
                         f"other {100 * wins[~hit].mean():5.1f}%")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--controller", default="learned")
    parser.add_argument("--episodes", type=int, default=30, help="episodes per schedule")
    parser.add_argument("--schedules", default=",".join(SCHEDULES))
    parser.add_argument("--switch", type=int, default=None,
                        help="the decision at which a schedule switches (default: half the episode's decisions)")
    parser.add_argument("--replan-every", type=int, default=4)
    parser.add_argument("--decoys", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="seeds the decoys and the uniform draws")
    parser.add_argument("--seeds", choices=list(SEED_SET_KINDS), default="dev",
                        help="the episodes: the task's development seeds (dev, MIKASA's 5000 + i), or its protocol's "
                             "test set (protocol, 4242424242 + i), for a final figure only")
    parser.add_argument("--out", default=None, help="write the per-episode records here (JSON)")
    args = parser.parse_args()
    task = make_task(args.task)
    controller = make_controller(args.controller, task)
    switch = -(-task.max_control_steps // args.replan_every) // 2 if args.switch is None else args.switch
    try:
        records = play(task, controller, [s for s in args.schedules.split(",") if s], args.episodes, switch,
                       args.replan_every, args.decoys, args.seed, verbose=True,
                       held_out=SEED_SET_KINDS[args.seeds])
    except ValueError as err:
        parser.error(str(err))
    print("\n".join(uniform_breakdown(records, switch)))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(dict(task=task.name, controller=args.controller, switch=switch, records=records), f, indent=1)


if __name__ == "__main__":
    main()
