"""Compare training runs that differ only in their seed: when retrieval was learned and where it ended.

Reads each run folder's evaluations.jsonl and summary.json (``sb3-memret train recall --seed S
--out runs/recall-seedS``) and prints one row per run plus the mean and standard deviation.
Usage: ``python scripts/seed_sweep.py runs/recall-seed0 runs/recall-seed1 ...``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from sb3_memret.analysis.report import MASTERY, first_mastered
from sb3_memret.training import read_history


def run_row(run: Path) -> dict[str, float]:
    """The figures of one run; ``first_mastered`` (an evaluated round) is NaN when greedy accuracy never
    reached MASTERY."""
    history = read_history(run)
    if not history:
        raise SystemExit(f"{run}: no evaluations.jsonl, so not a training run")
    summary = json.loads((run / "summary.json").read_text()) if (run / "summary.json").exists() else {}
    mastered = row["round"] if (row := first_mastered(history)) else float("nan")
    last = history[-1]
    return {"seed": summary.get("seed", "?"), "first_mastered": mastered, "round": last["round"],
            "greedy": last["greedy_accuracy"], "sampled": last["sampled_fraction"], "entropy": last["entropy"],
            "success": last["success"]["overall"], "minutes": summary.get("wall_seconds", float("nan")) / 60}


def _mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and standard deviation over the runs that have the figure (NaN where none has)."""
    present = [v for v in values if not np.isnan(v)]
    return (float(np.mean(present)), float(np.std(present))) if present else (float("nan"), float("nan"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    runs = parser.parse_args().runs
    rows = [run_row(run) for run in runs]
    keys = ["first_mastered", "greedy", "sampled", "entropy", "success", "minutes"]
    print(f"| run | seed | first round with greedy ≥ {MASTERY:.0%} | last round | greedy | sampled | entropy | "
          "success | minutes |")
    print("|---|---|---|---|---|---|---|---|---|")
    for run, row in zip(runs, rows):
        print(f"| {run.name} | {row['seed']} | {row['first_mastered']} | {row['round']} | {row['greedy']:.0%} | "
              f"{row['sampled']:.0%} | {row['entropy']:.2f} | {row['success']:.0%} | {row['minutes']:.1f} |")
    stats = {k: _mean_std([r[k] for r in rows]) for k in keys}
    mastered = sum(not np.isnan(r["first_mastered"]) for r in rows)
    print(f"| mean ± std | | {stats['first_mastered'][0]:.1f} ± {stats['first_mastered'][1]:.1f} "
          f"({mastered} of {len(rows)} runs reached it) | | "
          f"{stats['greedy'][0]:.0%} ± {stats['greedy'][1]:.0%} | {stats['sampled'][0]:.0%} ± {stats['sampled'][1]:.0%} | "
          f"{stats['entropy'][0]:.2f} ± {stats['entropy'][1]:.2f} | {stats['success'][0]:.0%} ± {stats['success'][1]:.0%} | "
          f"{stats['minutes'][0]:.1f} |")


if __name__ == "__main__":
    main()
