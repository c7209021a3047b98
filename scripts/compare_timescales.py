"""Stores by timescale against one bank, and the learned retention critic against fixed rules, paired episode by episode.

Each RUN is a training run folder (``train recall --config zoo_configs/memret_ppo_timescales.yml`` or
``..._one_bank.yml``); its model is played with each eviction rule (``--rules``: the learned critic, ``fifo``,
``lru``, ``prior``) on the same held-out task seeds, so every comparison pairs the same episodes. Prints success and
how often the true fact was evicted per run and rule, then for each pair of (layout, rule) rows pooled over the
runs' training seeds: the successes each has that the other lacks, and the exact two-sided McNemar p-value on
those discordant pairs. ``--out FILE`` keeps every episode's outcome as JSON; ``--add FILE...`` pools the outcomes
such files hold with this call's (runs played in several calls, compared as one).

Usage: ``python scripts/compare_timescales.py runs/timescales-seed0 runs/timescales_one_bank-seed0 --episodes 48``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO

from sb3_memret.common.seeds import HELD_OUT_SEED
from sb3_memret.envs.configs import with_retention
from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.evaluation.retrieval import evaluate_retrieval
from sb3_memret.memory.retention import RETENTION_RULES
from sb3_memret.training.run import eval_env_kwargs


def play(model_path: Path, rule: str, episodes: int, controller: str, held_out: str) -> tuple[str, list[dict]]:
    """The run's layout ("stores" or "one bank") and each episode's outcome with ``rule`` evicting, at the task's
    held-out seeds, or where it has none (the drawer) at seeds drawn from the held-out seed: the same episodes for
    every run and rule."""
    model = PPO.load(model_path, device="cpu")
    torch.set_num_threads(1)  # physics in this process: idle intra-op threads would spin-wait after every small op
    kwargs = with_retention(eval_env_kwargs(model, model_path, "recall", controller), rule)
    layout = "stores" if kwargs.get("stores") else "one bank"
    venv = make_recall_vec_env(1, kwargs)
    outcomes: list[dict[str, Any]] = []
    seeds = venv.unwrapped.held_out_seed_blocks([episodes], held_out)
    task_seeds = None if seeds is not None else \
        [int(s) for s in np.random.default_rng(HELD_OUT_SEED).integers(0, 2**31, episodes)]
    try:
        evaluate_retrieval(model, venv, episodes, seed=0, on_episode=outcomes.append, held_out=held_out,
                           task_seeds=task_seeds)
    finally:
        venv.close()
    return layout, outcomes


def show(row: dict[str, Any]) -> None:
    outcomes = row["episodes"]
    success = sum(o["success"] for o in outcomes) / len(outcomes)
    evicted = sum(o["true_evicted"] for o in outcomes) / len(outcomes)
    print(f"| {Path(row['run']).name} | {row['layout']} | {row['rule']} | {success:.1%} | {evicted:.1%} | "
          f"{len(outcomes)} |", flush=True)


def mcnemar_p(only_a: int, only_b: int) -> float:
    """Exact two-sided McNemar p-value: under no difference each discordant pair favours either side with 1/2."""
    n = only_a + only_b
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, k) for k in range(min(only_a, only_b) + 1)) / 2 ** n
    return min(1.0, 2 * tail)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="*", type=Path)
    parser.add_argument("--add", nargs="*", type=Path, default=[], help="--out files of earlier calls to pool.")
    parser.add_argument("--model", default="final_model.zip", help="Model file inside each run folder.")
    parser.add_argument("--rules", default=",".join(RETENTION_RULES), help="Comma list of eviction rules.")
    parser.add_argument("--episodes", type=int, default=48)
    parser.add_argument("--controller", default="scripted")
    parser.add_argument("--held-out", default="development", choices=["evaluation", "development"],
                        help="The task's seeds to play: those checkpoints are chosen on, or its protocol's (the test "
                             "set: the final figure only).")
    parser.add_argument("--out", type=Path, default=None, help="Write every episode's outcome here (JSON).")
    args = parser.parse_args()
    rules = [r for r in args.rules.split(",") if r]
    unknown = [r for r in rules if r not in RETENTION_RULES]
    if unknown:
        raise SystemExit(f"unknown rules {unknown}; expected a comma list of {list(RETENTION_RULES)}")

    played: dict[tuple[str, str], dict[tuple[str, int], dict]] = defaultdict(dict)  # (layout, rule) -> episodes
    rows = [row for path in args.add for row in json.loads(path.read_text())]
    print("| run | layout | retention | success | true fact evicted | episodes |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        show(row)
    for run in args.runs:
        for rule in rules:
            layout, outcomes = play(run / args.model, rule, args.episodes, args.controller, args.held_out)
            rows.append({"run": str(run), "layout": layout, "rule": rule, "episodes": outcomes})
            show(rows[-1])
    for row in rows:
        seed_of_run = Path(row["run"]).name.rsplit("seed", 1)[-1]  # runs of one training seed pair up
        for o in row["episodes"]:
            played[row["layout"], row["rule"]][seed_of_run, o["task_seed"]] = o

    print("\n| A | B | pairs | A success | B success | A only | B only | McNemar p |")
    print("|---|---|---|---|---|---|---|---|")
    for a, b in itertools.combinations(sorted(played), 2):
        shared = sorted(set(played[a]) & set(played[b]))  # the same training seed and task seed
        if not shared:
            continue
        wins_a = [played[a][k]["success"] for k in shared]
        wins_b = [played[b][k]["success"] for k in shared]
        only_a = sum(x and not y for x, y in zip(wins_a, wins_b))
        only_b = sum(y and not x for x, y in zip(wins_a, wins_b))
        print(f"| {' '.join(a)} | {' '.join(b)} | {len(shared)} | {sum(wins_a) / len(shared):.1%} | "
              f"{sum(wins_b) / len(shared):.1%} | {only_a} | {only_b} | {mcnemar_p(only_a, only_b):.3g} |")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
