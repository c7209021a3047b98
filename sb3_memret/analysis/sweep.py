"""Training runs that differ only in their seed, side by side: when retrieval was learned, whether it held, and
where it ended (the table ``scripts/seed_sweep.py`` prints and the docs' results pages draw from committed runs)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator, PercentFormatter

from sb3_memret.training.run import read_history

MASTERY = 0.95  # greedy accuracy that counts as "learned"


def first_mastered(history: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The first evaluation whose greedy accuracy reached MASTERY, or None."""
    return next((row for row in history if row["greedy_accuracy"] >= MASTERY), None)


def is_run(folder: Path) -> bool:
    """Whether ``folder`` holds a finished training run (its summary and its held-out evaluations)."""
    return (folder / "summary.json").is_file() and (folder / "evaluations.jsonl").is_file()


def run_row(run: Path) -> dict[str, Any]:
    """The figures of one run. ``first_mastered`` (an evaluated round) and ``mastered_decisions`` (the decisions
    trained by then) are NaN when greedy accuracy never reached MASTERY; ``held`` says whether every evaluation
    after it stayed at MASTERY or above, ``held_from_middle`` whether every one from the run's middle round on did."""
    run = Path(run)
    history = read_history(run)
    if not history:
        raise ValueError(f"{run}: no evaluations.jsonl, so not a training run")
    summary = json.loads((run / "summary.json").read_text()) if (run / "summary.json").exists() else {}
    first = first_mastered(history)
    last = history[-1]
    baselines = summary.get("baselines") or {}  # the report's, on the final evaluation's episodes
    baseline = {name: baselines[name]["success"]["overall"] if name in baselines else float("nan")
                for name in ("oracle", "none")}
    held = first is not None and all(row["greedy_accuracy"] >= MASTERY for row in history
                                     if row["round"] >= first["round"])
    middle = [row for row in history if row["round"] >= last["round"] / 2]
    return {"run": run.name, "seed": summary.get("seed", "?"),
            "first_mastered": first["round"] if first else float("nan"),
            "mastered_decisions": first["timesteps"] if first else float("nan"), "held": held,
            "held_from_middle": all(row["greedy_accuracy"] >= MASTERY for row in middle),
            "lowest_from_middle": min(row["greedy_accuracy"] for row in middle),
            "evaluations": len(history), "round": last["round"], "episodes": last["episodes"],
            "greedy": last["greedy_accuracy"], "sampled": last["sampled_fraction"], "entropy": last["entropy"],
            "success": last["success"]["overall"], "oracle": baseline["oracle"], "none": baseline["none"],
            "minutes": summary.get("wall_seconds", float("nan")) / 60}


def _mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and standard deviation over the runs that have the figure (NaN where none has)."""
    present = [v for v in values if not np.isnan(v)]
    return (float(np.mean(present)), float(np.std(present))) if present else (float("nan"), float("nan"))


def sweep_table(rows: Sequence[dict[str, Any]], oracle: float | None = None) -> list[str]:
    """The markdown table of ``rows`` (``run_row``'s), one line a run and their mean ± std. Each run's final success
    is set over the oracle's (the true fact in the prompt) on the same episodes: its own report's, else ``oracle``
    (played once for all); the no-memory baseline beside it where the report played it."""
    rows = [{**row, "oracle": row["oracle"] if not np.isnan(row["oracle"]) else (oracle if oracle else float("nan"))}
            for row in rows]
    baselines = any(not np.isnan(row["oracle"]) for row in rows)

    def percent(value: float) -> str:
        return "–" if np.isnan(value) else f"{value:.0%}"

    extra_head, extra_rule = ("oracle | none | recall / oracle | ", "---|---|---|") if baselines else ("", "")
    lines = [f"| run | seed | evaluations | first round with greedy ≥ {MASTERY:.0%} (decisions) | held after | "
             f"≥ {MASTERY:.0%} from the middle on (lowest) | last round | episodes | greedy | sampled | entropy | "
             f"success | {extra_head}training minutes |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|" + extra_rule + "---|"]
    for row in rows:
        extra = ""
        if baselines:
            ratio = "–" if np.isnan(row["oracle"]) or not row["oracle"] else f"{row['success'] / row['oracle']:.2f}"
            extra = f"{percent(row['oracle'])} | {percent(row['none'])} | {ratio} | "
        first = "never" if np.isnan(row["first_mastered"]) else f"{row['first_mastered']} ({row['mastered_decisions']})"
        lines.append(f"| {row['run']} | {row['seed']} | {row['evaluations']} | {first} | "
                     f"{'yes' if row['held'] else 'no'} | "
                     f"{'yes' if row['held_from_middle'] else 'no'} ({row['lowest_from_middle']:.0%}) | "
                     f"{row['round']} | {row['episodes']} | {row['greedy']:.1%} | {row['sampled']:.1%} | "
                     f"{row['entropy']:.2f} | {row['success']:.0%} | {extra}{row['minutes']:.1f} |")
    stats = {k: _mean_std([r[k] for r in rows]) for k in ("first_mastered", "greedy", "sampled", "entropy", "success",
                                                          "oracle", "none", "minutes")}
    mastered = sum(not np.isnan(r["first_mastered"]) for r in rows)
    extra = ""
    if baselines:
        ratio = stats["success"][0] / stats["oracle"][0] if stats["oracle"][0] else float("nan")
        extra = f"{percent(stats['oracle'][0])} | {percent(stats['none'][0])} | {ratio:.2f} | "
    lines.append(f"| mean ± std | | | {stats['first_mastered'][0]:.1f} ± {stats['first_mastered'][1]:.1f} "
                 f"({mastered} of {len(rows)} reached it) | {sum(r['held'] for r in rows)} of {len(rows)} | "
                 f"{sum(r['held_from_middle'] for r in rows)} of {len(rows)} | | | "
                 f"{stats['greedy'][0]:.1%} ± {stats['greedy'][1]:.1%} | "
                 f"{stats['sampled'][0]:.1%} ± {stats['sampled'][1]:.1%} | "
                 f"{stats['entropy'][0]:.2f} ± {stats['entropy'][1]:.2f} | "
                 f"{stats['success'][0]:.0%} ± {stats['success'][1]:.0%} | {extra}{stats['minutes'][0]:.1f} |")
    return lines


def plot_sweep(runs: Sequence[Path], out: Path, title: str | None = None) -> Path:
    """Each run's held-out greedy accuracy, sampled fraction and entropy by round, in one PNG at ``out``."""
    fig = Figure(figsize=(10, 4), layout="constrained")
    accuracy, entropy = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    for run in runs:
        history = read_history(run)
        seed = json.loads((Path(run) / "summary.json").read_text()).get("seed", Path(run).name)
        rounds = [row["round"] for row in history]
        line, = accuracy.plot(rounds, [row["greedy_accuracy"] for row in history], marker="o", label=f"seed {seed}")
        accuracy.plot(rounds, [row["sampled_fraction"] for row in history], color=line.get_color(), linestyle=":")
        entropy.plot(rounds, [row["entropy"] for row in history], color=line.get_color(), marker="^")
    accuracy.axhline(MASTERY, color="grey", linestyle="--", linewidth=0.8)
    accuracy.set(xlabel="PPO round", ylabel="held-out greedy (solid) / sampled (dotted)", ylim=(-0.02, 1.02))
    accuracy.yaxis.set_major_formatter(PercentFormatter(xmax=1))
    entropy.set(xlabel="PPO round", ylabel="held-out policy entropy (nats)", ylim=(0, None))
    for ax in (accuracy, entropy):
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    accuracy.legend(fontsize="small")
    if title:
        fig.suptitle(title)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    return out


__all__ = ["MASTERY", "first_mastered", "is_run", "plot_sweep", "run_row", "sweep_table"]
