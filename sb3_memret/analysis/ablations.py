"""Controller ablations: how a frozen controller consumes memory (the seed paper's Tables 1-3).

Each ablation is a grid of cells; a cell is a prompt, a cube layer and a replan interval,
played for the same ``episodes`` held-out placements (seeds ``seed .. seed+episodes-1``) as
every other cell, so cells differ only in what they vary.

- ``replan``: oracle memory, success per layer for each replan interval (Table 1).
- ``prompt``: correct/wrong object word x correct/wrong layer, plus the bare prompt, with the
  cube in one layer (Table 2).
- ``memcount``: zero, one (oracle) and two (oracle + another true fact) memories, per layer
  (Table 3).
- ``wording``: the oracle memory reworded in ways no training prompt was, per layer. Its cells
  waive the prompt contract, which every other command enforces: that is what it measures.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from sb3_memret.controllers.base import FrozenController
from sb3_memret.tasks.drawer.cabinet import LAYERS, check_layer
from sb3_memret.parallel_rollout import EpisodeJob, run_jobs
from sb3_memret.prompts import HOLDING_NOTHING_TEXT, INSTRUCTION, build_prompt
from sb3_memret.tasks.drawer.prompts import location_text
from sb3_memret.rollout import DEFAULT_REPLAN_EVERY, EpisodeResult
from sb3_memret.seeds import HELD_OUT_SEED

REPLAN_INTERVALS: tuple[int, ...] = (5, 8, 10, 12, 16, 20, 24, 28, 32)
WRONG_OBJECT = "key"
OVERALL = "overall"


@dataclass(frozen=True)
class Cell:
    """One table cell: the episodes' prompt, cube layer and replan interval."""

    row: str
    column: str
    prompt: str
    layer: int
    replan_every: int = DEFAULT_REPLAN_EVERY
    check_prompt: bool = True


@dataclass(frozen=True)
class AblationSpec:
    """A table to fill: its rows, columns and cells (a missing (row, column) prints as '–')."""

    name: str
    title: str
    row_header: str
    rows: tuple[str, ...]
    columns: tuple[str, ...]
    cells: tuple[Cell, ...]
    pooled_column: str | None = None  # a column pooling each row's episodes (the overall rate)


@dataclass
class CellResult:
    """A cell's outcome: successes out of episodes, with a 95% Wilson interval and the median
    control steps of the successful episodes (None without one)."""

    row: str
    column: str
    prompt: str
    layer: int
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
        fields = ["ablation", "row", "column", "layer", "replan_every", "episodes", "successes", "success",
                  "ci_low", "ci_high", "median_steps", "prompt"]
        writer = csv.DictWriter(buffer, fieldnames=fields, lineterminator="\n")
        writer.writeheader()
        for cell in self.cells:
            writer.writerow({"ablation": self.spec.name, **{k: v for k, v in asdict(cell).items() if k in fields},
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


def _layer_column(layer: int) -> str:
    return f"layer {layer}"


def replan_ablation(intervals: Sequence[int] = REPLAN_INTERVALS) -> AblationSpec:
    """Oracle memory; success per layer for each replan interval."""
    if not intervals or any(i < 1 for i in intervals):
        raise ValueError(f"replan intervals must be positive integers, got {list(intervals)}")
    rows = tuple(str(i) for i in intervals)
    cells = tuple(Cell(str(i), _layer_column(layer), build_prompt(INSTRUCTION, [location_text("cube", layer)]), layer, i)
                  for i in intervals for layer in LAYERS)
    return AblationSpec("replan", "Replan interval: success with the oracle memory", "replan steps", rows,
                        (*map(_layer_column, LAYERS), OVERALL), cells, pooled_column=OVERALL)


def prompt_ablation(layer: int = 2, replan_every: int = DEFAULT_REPLAN_EVERY) -> AblationSpec:
    """The cube in ``layer``; correct/wrong object word x correct/wrong layer, and the bare prompt."""
    check_layer(layer)
    wrong_layer = layer % len(LAYERS) + 1
    correct_word, wrong_word = "correct object word (cube)", f"wrong object word ({WRONG_OBJECT})"
    none_row = "no-memory prompt"
    cells = []
    for row, entity in ((correct_word, "cube"), (wrong_word, WRONG_OBJECT)):
        for column, named in (("correct layer", layer), ("wrong layer", wrong_layer)):
            cells.append(Cell(row, column, build_prompt(INSTRUCTION, [location_text(entity, named)]), layer, replan_every))
    cells.append(Cell(none_row, "wrong layer", build_prompt(INSTRUCTION, []), layer, replan_every))
    return AblationSpec("prompt", f"Prompt ablation: cube in drawer layer {layer}", "prompt condition",
                        (correct_word, wrong_word, none_row), ("correct layer", "wrong layer"), tuple(cells))


def memcount_ablation(replan_every: int = DEFAULT_REPLAN_EVERY) -> AblationSpec:
    """Zero, one (oracle) and two (oracle + 'the robot is holding nothing.', true at the start) memories."""
    rows = {"no memory (bare prompt)": lambda layer: [],
            "one memory (oracle)": lambda layer: [location_text("cube", layer)],
            "two memories (oracle + true)": lambda layer: [location_text("cube", layer), HOLDING_NOTHING_TEXT]}
    cells = tuple(Cell(row, _layer_column(layer), build_prompt(INSTRUCTION, memories(layer)), layer, replan_every)
                  for row, memories in rows.items() for layer in LAYERS)
    return AblationSpec("memcount", "Memory count: success per layer", "condition", tuple(rows),
                        (*map(_layer_column, LAYERS), OVERALL), cells, pooled_column=OVERALL)


ORDINALS = {1: "first", 2: "second", 3: "third"}
# The trained wording first, as the reference; then paraphrases never in any training prompt.
WORDINGS: tuple[str, ...] = (
    "the cube is in drawer layer {layer}.",
    "the cube is inside drawer layer {layer}.",
    "the cube is located in drawer layer {layer}.",
    "the cube is in layer {layer}.",
    "the cube is in drawer {layer}.",
    "the cube is in the {ordinal} drawer.",
    "drawer layer {layer} holds the cube.",
)


def wording_ablation(replan_every: int = DEFAULT_REPLAN_EVERY, wordings: Sequence[str] = WORDINGS) -> AblationSpec:
    """The oracle memory in each wording, per layer; prompts are not checked against the template."""
    rows = tuple(w.replace("{layer}", "L").replace("{ordinal}", "N-th") for w in wordings)
    cells = tuple(
        Cell(row, _layer_column(layer),
             f"{INSTRUCTION} {wording.format(layer=layer, ordinal=ORDINALS[layer])}", layer, replan_every,
             check_prompt=False)
        for row, wording in zip(rows, wordings) for layer in LAYERS)
    return AblationSpec("wording", "Memory wording: success with the oracle memory reworded", "memory sentence", rows,
                        (*map(_layer_column, LAYERS), OVERALL), cells, pooled_column=OVERALL)


ABLATIONS: dict[str, Callable[..., AblationSpec]] = {
    "replan": replan_ablation,
    "prompt": prompt_ablation,
    "memcount": memcount_ablation,
    "wording": wording_ablation,
}


def run_ablation(
    spec: AblationSpec,
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
    """Play every cell for ``episodes`` placements (seeds seed..seed+episodes-1) over ``n_envs`` envs served
    by one controller (``run_jobs``; ``backend`` and ``ray_address`` place the physics). ``built`` is the
    controller ``controller`` names when the caller has already built it."""
    if episodes < 1:
        raise ValueError(f"episodes per cell must be >= 1, got {episodes}")
    jobs = [EpisodeJob(cell.prompt, cell.layer, seed + k, cell.replan_every, cell.check_prompt) for cell in spec.cells for k in range(episodes)]
    results = run_jobs(built or controller, jobs, n_envs, render_backend, on_episode, backend, ray_address)
    cells = []
    for i, cell in enumerate(spec.cells):
        outcome = results[i * episodes:(i + 1) * episodes]
        wins = [r.steps for r in outcome if r.success]
        cells.append(CellResult(cell.row, cell.column, cell.prompt, cell.layer, cell.replan_every, episodes, len(wins),
                                tuple(wins)))
    return AblationResult(spec, episodes, seed, controller, cells)


__all__ = ["ABLATIONS", "AblationResult", "AblationSpec", "Cell", "CellResult", "REPLAN_INTERVALS", "memcount_ablation",
           "prompt_ablation", "replan_ablation", "run_ablation", "wilson_interval", "wording_ablation"]
