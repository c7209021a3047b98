"""Learning curves of a training run (the seed paper's Figure 5), read from its run folder.

Drawn on a bare :class:`matplotlib.figure.Figure` (no pyplot), so nothing depends on or changes the
active backend and no figure stays registered after saving.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator, PercentFormatter

from sb3_memret.common.run_logger import PROGRESS_CSV
from sb3_memret.training.run import HISTORY_FILE, read_history

PLOT_FILE = "learning_curves.png"


@dataclass
class LearningCurves:
    """A run's per-round training series (progress.csv) and per-evaluation held-out series (evaluations.jsonl)."""

    train_round: np.ndarray
    train_sampled_fraction: np.ndarray
    train_entropy: np.ndarray  # NaN for rounds logged before any update
    eval_round: np.ndarray
    eval_greedy_accuracy: np.ndarray
    eval_sampled_fraction: np.ndarray
    eval_entropy: np.ndarray
    eval_success: np.ndarray


def _number(cell: str | None) -> float:
    """A CSV cell as a float; an empty cell or a missing column is NaN."""
    return float(cell) if cell else math.nan


def learning_curves(run: Path) -> LearningCurves:
    """The curves of the run in folder ``run``; a round is a progress.csv row that collected a rollout."""
    run = Path(run)
    progress, history_path = run / PROGRESS_CSV, run / HISTORY_FILE
    if not progress.exists() and not history_path.exists():
        raise FileNotFoundError(f"no training logs in {run}: expected {PROGRESS_CSV} and/or {HISTORY_FILE}")
    rows = []
    if progress.exists():
        with open(progress, newline="") as f:
            rows = [row for row in csv.DictReader(f) if row.get("rollout/sampled_fraction")]
    history = read_history(run)
    if not rows and not history:
        raise ValueError(f"{progress} and {history_path} hold no rounds or evaluations")
    return LearningCurves(
        train_round=np.arange(len(rows)),
        train_sampled_fraction=np.array([_number(row["rollout/sampled_fraction"]) for row in rows]),
        train_entropy=-np.array([_number(row.get("train/entropy_loss")) for row in rows]),
        eval_round=np.array([row["round"] for row in history], dtype=int),
        eval_greedy_accuracy=np.array([row["greedy_accuracy"] for row in history], dtype=float),
        eval_sampled_fraction=np.array([row["sampled_fraction"] for row in history], dtype=float),
        eval_entropy=np.array([row["entropy"] for row in history], dtype=float),
        eval_success=np.array([row["success"]["overall"] for row in history], dtype=float),
    )


def _plot(ax: Axes, x: np.ndarray, y: np.ndarray, **style) -> None:
    """Draw one series, skipping it when it has no data so the legend lists only what is shown."""
    if np.isfinite(y).any():
        ax.plot(x, y, **style)


def plot_learning_curves(run: Path, out: Path | None = None, title: str | None = None,
                         chance: float | None = None) -> Path:
    """Save the run's Figure 5 as a PNG: at each held-out evaluation greedy accuracy, sampled fraction (the chance a
    training-time draw holds the true memory), entropy and success, and per PPO round the training draws' share that
    held it and the training entropy.

    ``chance`` (1/capacity) draws the random-retrieval baseline when given; the PNG goes to
    ``out`` (default ``run/learning_curves.png``), whose path is returned.
    """
    run = Path(run)
    curves = learning_curves(run)
    out = Path(out) if out is not None else run / PLOT_FILE
    fig = Figure(figsize=(8, 5), layout="constrained")
    ax = fig.add_subplot()
    entropy_ax = ax.twinx()
    _plot(ax, curves.eval_round, curves.eval_greedy_accuracy, color="tab:blue", marker="o",
          label="held-out greedy accuracy")
    _plot(ax, curves.eval_round, curves.eval_sampled_fraction, color="tab:orange", marker="D", markersize=5,
          label="held-out sampled fraction")
    _plot(ax, curves.train_round, curves.train_sampled_fraction, color="tab:orange", alpha=0.35, linewidth=1,
          label="training draws holding the true memory")
    _plot(ax, curves.eval_round, curves.eval_success, color="tab:green", marker="s", markersize=4,
          label="held-out success")
    if chance is not None:
        ax.axhline(chance, color="grey", linestyle="--", label=f"chance ({chance:.0%})")
    _plot(entropy_ax, curves.train_round, curves.train_entropy, color="tab:purple", alpha=0.6,
          label="policy entropy (training)")
    _plot(entropy_ax, curves.eval_round, curves.eval_entropy, color="tab:purple", marker="^", linestyle="none",
          label="policy entropy (held-out)")
    ax.set(xlabel="PPO round", ylabel="retrieval accuracy / success", ylim=(-0.02, 1.02), title=title or run.name)
    ax.yaxis.set_major_formatter(PercentFormatter(xmax=1))
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    entropy_ax.set_ylabel("policy entropy (nats)")
    entropy_ax.set_ylim(bottom=0)
    handles, labels = ax.get_legend_handles_labels()
    more_handles, more_labels = entropy_ax.get_legend_handles_labels()
    fig.legend(handles + more_handles, labels + more_labels, loc="outside lower center", ncols=3, fontsize="small")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=150)
    return out
