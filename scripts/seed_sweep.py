"""Compare training runs that differ only in their seed: when retrieval was learned, whether it held, and
where it ended against the oracle.

Reads each run folder's evaluations.jsonl and summary.json (``sb3-memret train recall --seed S
--out runs/recall-seedS``) and prints one row per run plus the mean and standard deviation:

- the first evaluated round whose held-out greedy accuracy reached 95% (and the decisions trained by then,
  which compare runs whose rounds differ in size), and whether every later evaluation stayed at or above
  it ("held");
- the final evaluation's greedy accuracy, success and entropy;
- with ``--oracle-episodes N``, the oracle condition (the true fact in the prompt, retrieval unused) on the
  runs' held-out episodes, played once since it does not depend on the retriever, and each run's final
  recall success over it.

With ``--against RUN ...`` (runs of another configuration, say the MLP beside the set retriever), a second
table pairs the runs by seed: each side's first mastered round and final success, and how many seeds the
first configuration mastered no later (in decisions trained) and ended no worse on.

Usage: ``python scripts/seed_sweep.py runs/recall-seed0 runs/recall-seed1 ... [--oracle-episodes 50]
[--against runs/mlp-seed0 ...]``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from sb3_memret.analysis.sweep import run_row, sweep_table


def oracle_success(run: Path, episodes: int, n_envs: int) -> float:
    """Success of the oracle prompt on the run's held-out episodes, with the run's controller."""
    from sb3_memret.evaluation.retrieval import evaluate_retrieval
    from sb3_memret.envs.vec_env import make_recall_vec_env
    from sb3_memret.policy.ppo import load_model
    from sb3_memret.training.run import eval_env_kwargs

    summary = json.loads((run / "summary.json").read_text())
    path = run / "final_model.zip"
    model = load_model(path)
    venv = make_recall_vec_env(n_envs, eval_env_kwargs(model, path, "oracle", summary["controller"]))
    try:
        return evaluate_retrieval(model, venv, episodes, seed=summary["eval_seed"]).success["overall"]
    finally:
        venv.close()


def _mastered(row: dict[str, Any]) -> str:
    """'round (decisions)' of a run's first mastered evaluation, or 'never'."""
    return "never" if np.isnan(row["first_mastered"]) else f"{row['first_mastered']} ({row['mastered_decisions']})"


def print_paired(rows: list[dict[str, Any]], against: list[dict[str, Any]]) -> None:
    """Both configurations side by side, seed by seed (seeds run by only one side are left out)."""
    by_seed = {row["seed"]: row for row in against}
    pairs = [(row, by_seed[row["seed"]]) for row in rows if row["seed"] in by_seed]
    if not pairs:
        raise SystemExit("--against: no run shares a seed with the runs compared")
    print("\n| seed | first mastered, round (decisions): these / against | final success: these / against | "
          "final greedy: these / against |")
    print("|---|---|---|---|")
    never = float("inf")  # a run that never mastered is later than any that did
    no_later = no_worse = 0
    for mine, theirs in pairs:
        first = [never if np.isnan(r["mastered_decisions"]) else r["mastered_decisions"] for r in (mine, theirs)]
        no_later += first[0] <= first[1]
        no_worse += mine["success"] >= theirs["success"]
        print(f"| {mine['seed']} | {_mastered(mine)} / {_mastered(theirs)} | {mine['success']:.0%} / "
              f"{theirs['success']:.0%} | {mine['greedy']:.0%} / {theirs['greedy']:.0%} |")
    print(f"\nmastered no later on {no_later} of {len(pairs)} seeds; final success no lower on {no_worse} of {len(pairs)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--oracle-episodes", type=int, default=0,
                        help="play the oracle condition on this many held-out episodes (0: skip)")
    parser.add_argument("--n-envs", type=int, default=2, help="envs for the oracle episodes")
    parser.add_argument("--against", nargs="+", type=Path, default=[],
                        help="runs of another configuration to pair with these by seed")
    args = parser.parse_args()
    rows = [run_row(run) for run in args.runs]
    oracle = oracle_success(args.runs[0], args.oracle_episodes, args.n_envs) if args.oracle_episodes else None
    print("\n".join(sweep_table(rows, oracle)))
    if oracle is not None:
        print(f"\noracle success on the held-out episodes ({args.oracle_episodes}): {oracle:.0%}")
    if args.against:
        print_paired(rows, [run_row(run) for run in args.against])


if __name__ == "__main__":
    main()
