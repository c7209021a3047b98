"""The memory benchmark's comparisons for trained runs, each evaluated on the same held-out episodes:

- ``objects RUN...``: greedy retrieval accuracy and success on the training objects and on objects no
  training episode had (``--objects heldout``);
- ``observed RUN...``: success with the recalled memory against no memory and the oracle (the target's
  layer in the instruction), and recall / oracle;
- ``retention RUN...``: success, and what the long-term store kept before each task (the target's
  true fact, a stale one, or nothing though the target was seen since the last move), with the learned
  retention critic and with each fixed rule (fifo, lru, prior) evicting from the same model's banks.

Usage: ``python scripts/compare_memory.py objects runs/objects-seed0 [--controller learned] [--episodes 50]``.
Each RUN is a training run folder; its ``best_model.zip`` is evaluated (``--model final_model.zip`` for another),
in the run's env settings; ``--set KEY=VALUE`` changes one (e.g. ``--set memory_source=observed``).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3 import PPO

from sb3_memret.evaluation.retrieval import RetrievalReport, evaluate_retrieval
from sb3_memret.common.seeds import HELD_OUT_SEED
from sb3_memret.tasks.drawer.cabinet import LAYERS
from sb3_memret.tasks.drawer.objects import OBJECT_SETS
from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.memory.retention import RETENTION_RULES
from sb3_memret.training.run import eval_env_kwargs

def evaluate(model_path: Path, args: argparse.Namespace, mode: str = "recall", **overrides: Any) -> RetrievalReport:
    model = PPO.load(model_path, device="cpu")
    kwargs = {**eval_env_kwargs(model, model_path, mode, args.controller), **args.set, **overrides}
    venv = make_recall_vec_env(args.n_envs, kwargs)
    try:
        return evaluate_retrieval(model, venv, args.episodes, seed=args.seed)
    finally:
        venv.close()


def compare_objects(args: argparse.Namespace) -> None:
    print("| run | objects | greedy accuracy | success | decisions |")
    print("|---|---|---|---|---|")
    for run in args.runs:
        for objects in args.object_sets:
            report = evaluate(run / args.model, args, objects=objects)
            print(f"| {run.name} | {objects} | {report.greedy_accuracy:.1%} | {report.success['overall']:.0%} | "
                  f"{report.decisions} |")


def compare_observed(args: argparse.Namespace) -> None:
    print("| run | recall success | none | none, by layer 1/2/3 | oracle | recall / oracle | recall greedy accuracy |")
    print("|---|---|---|---|---|---|---|")
    for run in args.runs:
        reports = {mode: evaluate(run / args.model, args, mode) for mode in ("recall", "none", "oracle")}
        success = {mode: report.success["overall"] for mode, report in reports.items()}
        print(f"| {run.name} | {success['recall']:.0%} | {success['none']:.0%} | {_by_layer(reports['none'])} | "
              f"{success['oracle']:.0%} | "
              f"{success['recall'] / max(success['oracle'], 1e-9):.2f} | {reports['recall'].greedy_accuracy:.1%} |")


def compare_retention(args: argparse.Namespace) -> None:
    print("| run | retention | success | success, by layer 1/2/3 | target's fact kept | stale fact kept | "
          "needed fact gone | greedy accuracy |")
    print("|---|---|---|---|---|---|---|---|")
    for run in args.runs:
        for rule in args.rules:
            report = evaluate(run / args.model, args, retention=rule)
            print(f"| {run.name} | {rule} | {report.success['overall']:.0%} | {_by_layer(report)} | "
                  f"{report.target_fact_kept_rate:.0%} | {report.stale_fact_kept_rate:.0%} | "
                  f"{report.needed_fact_gone_rate:.0%} | {report.greedy_accuracy:.1%} |")


def _by_layer(report: RetrievalReport) -> str:
    """Success by the target's drawer: with no useful fact the controllers open the top one, so layer 1 is free."""
    return "/".join(f"{report.success.get(str(layer), float('nan')):.0%}" for layer in LAYERS)


def _setting(item: str) -> tuple[str, Any]:
    key, sep, value = item.partition("=")
    if not sep or not key:
        raise SystemExit(f"--set takes KEY=VALUE, got {item!r}")
    return key, yaml.safe_load(value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("comparison", choices=["objects", "observed", "retention"])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--model", default="best_model.zip", help="Model file inside each run folder.")
    parser.add_argument("--controller", default="scripted")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--n-envs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=HELD_OUT_SEED)
    parser.add_argument("--rules", nargs="+", choices=RETENTION_RULES, default=list(RETENTION_RULES),
                        help="retention: the eviction rules to compare.")
    parser.add_argument("--object-sets", nargs="+", choices=sorted(OBJECT_SETS), default=["train", "heldout"],
                        help="objects: which object sets to evaluate on.")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="Change one of the run's env settings (a YAML value).")
    args = parser.parse_args()
    args.set = dict(_setting(item) for item in args.set)
    {"objects": compare_objects, "observed": compare_observed, "retention": compare_retention}[args.comparison](args)


if __name__ == "__main__":
    main()
