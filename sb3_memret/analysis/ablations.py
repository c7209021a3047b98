"""Controller ablations: how a frozen controller consumes memory (the seed paper's Tables 1-3), as tables of cells.

A cell is a prompt, the task's reset options (which episode it plays: the drawer's cube layer) and a replan interval,
played for the same ``episodes`` held-out seeds (``seed .. seed+episodes-1``) as every other cell, so cells differ
only in what they vary. A task names the tables it defines (``Task.ablations``, their cells ``sb3_memret.tasks.ablations``:
the drawer's are the seed paper's replan, prompt, memcount and wording tables, kept with the drawer); here they are
played and their results tabled.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from sb3_memret.controllers.base import FrozenController
from sb3_memret.evaluation.parallel import EpisodeJob, run_jobs
from sb3_memret.evaluation.rollout import EpisodeResult
from sb3_memret.common.seeds import HELD_OUT_SEED
from sb3_memret.tasks import Task, make_task
from sb3_memret.tasks.ablations import AblationSpec, Cell

@dataclass
class CellResult:
    """A cell's outcome: successes out of episodes, with a 95% Wilson interval and the median
    control steps of the successful episodes (None without one)."""

    row: str
    column: str
    prompt: str
    reset_options: Mapping[str, Any]
    replan_every: int
    episodes: int
    successes: int
    win_steps: tuple[int, ...] = ()  # control steps of each successful episode
    ci_low: float = field(init=False)
    ci_high: float = field(init=False)

    def __post_init__(self) -> None:
        self.ci_low, self.ci_high = wilson_interval(self.successes, self.episodes)

    @property
    def success(self) -> float:
        return self.successes / self.episodes

    @property
    def median_steps(self) -> float | None:
        return float(np.median(self.win_steps)) if self.win_steps else None


@dataclass
class AblationResult:
    """A filled table and how it was produced."""

    spec: AblationSpec
    episodes: int
    seed: int
    controller: str
    cells: list[CellResult]

    def rate(self, row: str, column: str) -> float | None:
        """The success rate of a cell, the pooled rate of a row, or None where there is no cell."""
        if column == self.spec.pooled_column:
            group = [c for c in self.cells if c.row == row]
        else:
            group = [c for c in self.cells if c.row == row and c.column == column]
        episodes = sum(c.episodes for c in group)
        return sum(c.successes for c in group) / episodes if episodes else None

    def table(self) -> dict[str, dict[str, float | None]]:
        return {row: {col: self.rate(row, col) for col in self.spec.columns} for row in self.spec.rows}

    def to_markdown(self) -> str:
        """The table with its caption and the exact prompt of every row."""
        spec = self.spec
        lines = [f"**{spec.title}** ({self.episodes} episodes per cell, controller `{self.controller}`, "
                 f"placement seeds {self.seed}..{self.seed + self.episodes - 1})", "",
                 "| " + " | ".join((spec.row_header, *spec.columns)) + " |",
                 "|" + "---|" * (len(spec.columns) + 1)]
        for row, rates in self.table().items():
            lines.append("| " + " | ".join([row, *("–" if r is None else f"{r:.0%}" for r in rates.values())]) + " |")
        steps = {row: [n for c in self.cells if c.row == row for n in c.win_steps] for row in spec.rows}
        lines += ["", "Median control steps to success: " + " · ".join(
            f"{row}: {np.median(n):.0f}" if n else f"{row}: –" for row, n in steps.items())]
        lines += ["", "Prompts:"]
        for prompt in dict.fromkeys(c.prompt for c in self.cells):
            users = [c for c in self.cells if c.prompt == prompt]
            rows, columns = {c.row for c in users}, {c.column for c in users}
            where = [*rows] if len(rows) == 1 else []
            if len(columns) == 1 and not (where and sum(c.row == where[0] for c in self.cells) == 1):
                where += columns  # a row of one cell needs no column
            lines.append(f"- {', '.join(where) or 'every cell'}: `{prompt}`")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {"ablation": self.spec.name, "title": self.spec.title, "controller": self.controller,
                "episodes_per_cell": self.episodes, "seed": self.seed, "row_header": self.spec.row_header,
                "rows": list(self.spec.rows), "columns": list(self.spec.columns), "table": self.table(),
                "cells": [asdict(c) | {"success": c.success, "median_steps": c.median_steps} for c in self.cells]}

    def to_csv(self) -> str:
        """One line per cell, long format."""
        buffer = io.StringIO()
        fields = ["ablation", "row", "column", "reset_options", "replan_every", "episodes", "successes", "success",
                  "ci_low", "ci_high", "median_steps", "prompt"]
        writer = csv.DictWriter(buffer, fieldnames=fields, lineterminator="\n")
        writer.writeheader()
        for cell in self.cells:
            writer.writerow({"ablation": self.spec.name, **{k: v for k, v in asdict(cell).items() if k in fields},
                             "reset_options": json.dumps(dict(cell.reset_options), sort_keys=True),
                             "success": cell.success, "median_steps": cell.median_steps})
        return buffer.getvalue()


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a binomial rate (sensible at 0 and n, unlike the normal one)."""
    if n <= 0:
        raise ValueError(f"n must be >= 1, got {n}")
    if not 0 <= successes <= n:
        raise ValueError(f"successes must be in [0, {n}], got {successes}")
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, min(p, centre - half)), min(1.0, max(p, centre + half))  # p stays inside despite rounding


def run_ablation(
    spec: AblationSpec,
    task: Task | str,
    controller: str = "scripted",
    episodes: int = 17,
    seed: int = HELD_OUT_SEED,
    n_envs: int = 1,
    render_backend: str = "none",
    on_episode: Callable[[EpisodeJob, EpisodeResult], None] | None = None,
    backend: str = "auto",
    ray_address: str | None = None,
    built: FrozenController | None = None,
) -> AblationResult:
    """Play every cell of ``task`` for ``episodes`` seeds (seed..seed+episodes-1) over ``n_envs`` envs served
    by one controller (``run_jobs``; ``backend`` and ``ray_address`` place the physics). ``built`` is the
    controller ``controller`` names when the caller has already built it."""
    if episodes < 1:
        raise ValueError(f"episodes per cell must be >= 1, got {episodes}")
    task = make_task(task)
    jobs = [EpisodeJob(cell.prompt, seed + k, cell.reset_options, cell.replan_every, cell.check_prompt)
            for cell in spec.cells for k in range(episodes)]
    results = run_jobs(built or controller, jobs, task, n_envs, render_backend, on_episode, backend, ray_address)
    cells = []
    for i, cell in enumerate(spec.cells):
        outcome = results[i * episodes:(i + 1) * episodes]
        wins = [r.steps for r in outcome if r.success]
        cells.append(CellResult(cell.row, cell.column, cell.prompt, dict(cell.reset_options),
                                cell.replan_every or task.replan_every, episodes, len(wins), tuple(wins)))
    return AblationResult(spec, episodes, seed, controller, cells)


__all__ = ["AblationResult", "CellResult", "run_ablation", "wilson_interval"]
