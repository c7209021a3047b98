"""Published figures on the tasks a run shares with the literature, for the report to put beside its own.

``published_remember_color.csv`` beside this module carries what papers report on MIKASA-Robo's RememberColor3/5/9,
each with its source and how it was read (``paper table``, or ``quoted by others`` where only quotations of the
table could be read). They are the older 60-step ``RememberColorN-v0`` tasks, not the ``-VLA-v0`` ones: no per-task
figure on those has been published that we could find, so every row is marked with the task it was measured on.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

PUBLISHED = Path(__file__).with_name("published_remember_color.csv")


@dataclass(frozen=True)
class PublishedFigure:
    """One method's published success on one task (a fraction), with what it was measured on and where."""

    method: str
    task: str  # as the source names it (an older ``-v0`` task)
    vla_task: str  # the ``-VLA-v0`` task it stands beside
    success: float
    sem: float | None
    episodes: int
    read_from: str
    source: str


def published_figures(path: Path = PUBLISHED) -> list[PublishedFigure]:
    """Every row of the published-figures file; a ValueError names a row whose success is not a fraction."""
    figures = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            figure = PublishedFigure(row["method"], row["task"], row["vla_task"], float(row["success"]),
                                     float(row["sem"]) if row["sem"] else None, int(row["episodes"]),
                                     row["read_from"], row["source"])
            if not 0 <= figure.success <= 1:
                raise ValueError(f"{path}: {figure.method} on {figure.task} has success {figure.success}, "
                                 "not a fraction in [0, 1]")
            figures.append(figure)
    return figures


def published_section(ours: dict[str, str], controller: str, condition: str | None) -> list[str]:
    """Markdown lines: the published figures on the tasks in ``ours`` (env id -> our cell under ``condition``), a
    column per task, our row first (none when ``condition`` is None); no lines when the run shares no task with
    them."""
    figures = [f for f in published_figures() if f.vla_task in ours]
    if not figures:
        return []
    tasks = list(dict.fromkeys(f.vla_task for f in figures))
    methods = list(dict.fromkeys(f.method for f in figures))
    cell = {(f.method, f.vla_task): f for f in figures}
    old = ", ".join(dict.fromkeys(f.task for f in figures))
    lines = ["", "## Published figures beside ours", "",
             f"Published on MIKASA-Robo's older tasks ({old}: a 60-step horizon, another cue timing), 100 episodes "
             "per task, by policies trained on each task's demonstrations; ours are the -VLA-v0 tasks under this "
             "run's protocol. Not the same tasks: for orientation, not a ranking.", "",
             "| method | " + " | ".join(t.removesuffix("-VLA-v0") for t in tasks) + " | read from | source |",
             "|---|" + "---|" * (len(tasks) + 2)]
    if condition is not None:
        lines.append(f"| sb3-memret, {controller} controller, {condition} (this run, -VLA-v0) | "
                     + " | ".join(ours[t] for t in tasks) + " | this run | results.json |")
    for method in methods:
        row = [cell.get((method, t)) for t in tasks]
        values = [f"{100 * f.success:.0f}%" + (f" ± {100 * f.sem:.0f}" if f.sem is not None else "") if f else ""
                  for f in row]
        first = next(f for f in row if f)
        lines.append(f"| {method} | " + " | ".join(values) + f" | {first.read_from} | {first.source} |")
    return lines


__all__ = ["PUBLISHED", "PublishedFigure", "published_figures", "published_section"]
