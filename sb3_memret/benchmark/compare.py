"""Two benchmark runs (or two conditions of one) side by side, episode by episode: the same task at the same seed
played both ways, so a difference between them is counted on the episodes where they disagree (an exact McNemar
test), not on two success rates with their own sampling noise. This is how one controller or learner is chosen over
another on development seeds before a protocol run."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from scipy.stats import binomtest

from sb3_memret.benchmark.runner import RESULTS_FILE


@dataclass(frozen=True)
class PairedCell:
    """One task's episodes played in both runs (their common seeds): how many each won, and where they differ."""

    env_id: str
    both: int
    only_a: int
    only_b: int
    neither: int

    @property
    def episodes(self) -> int:
        return self.both + self.only_a + self.only_b + self.neither

    @property
    def a(self) -> int:
        return self.both + self.only_a

    @property
    def b(self) -> int:
        return self.both + self.only_b

    @property
    def p_value(self) -> float:
        """Exact McNemar: two-sided binomial test of the discordant episodes against even odds (1.0 without any)."""
        discordant = self.only_a + self.only_b
        return binomtest(self.only_a, discordant, 0.5).pvalue if discordant else 1.0


def load_results(run: Path) -> dict[str, Any]:
    """A run folder's results.json; a clear error when ``run`` is not a benchmark run folder."""
    path = Path(run) / RESULTS_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{run} holds no {RESULTS_FILE}: give a `sb3-memret benchmark mikasa --out` folder")
    return json.loads(path.read_text())


def _outcomes(results: dict[str, Any], env_id: str, condition: str) -> dict[int, bool]:
    cell = results["tasks"].get(env_id, {}).get("conditions", {}).get(condition) or {}
    return {int(seed): bool(success) for seed, success in zip(cell.get("seeds", []), cell.get("successes", []))}


def paired_cells(a: dict[str, Any], b: dict[str, Any], condition_a: str, condition_b: str) -> list[PairedCell]:
    """Every task that both runs played (``condition_a`` in ``a``, ``condition_b`` in ``b``) at common seeds, in
    ``a``'s order; a ValueError naming the conditions when no task has any."""
    cells = []
    for env_id in a["tasks"]:
        first, second = _outcomes(a, env_id, condition_a), _outcomes(b, env_id, condition_b)
        seeds = sorted(set(first) & set(second))
        if not seeds:
            continue
        pairs = [(first[s], second[s]) for s in seeds]
        cells.append(PairedCell(env_id, sum(x and y for x, y in pairs), sum(x and not y for x, y in pairs),
                                sum(y and not x for x, y in pairs), sum(not (x or y) for x, y in pairs)))
    if not cells:
        raise ValueError(f"no task was played under {condition_a!r} in the first run and {condition_b!r} in the "
                         "second at a common seed")
    return cells


def pooled(cells: list[PairedCell]) -> PairedCell:
    """Every task's episodes together (each episode counts once, so tasks weigh by their episodes)."""
    return PairedCell("all tasks", sum(c.both for c in cells), sum(c.only_a for c in cells),
                      sum(c.only_b for c in cells), sum(c.neither for c in cells))


def render_comparison(cells: list[PairedCell], label_a: str, label_b: str) -> str:
    """A markdown table: each task's successes both ways, the episodes where they differ, and McNemar's p."""
    lines = [f"A: {label_a}", f"B: {label_b}", "",
             "| task | episodes | A | B | only A | only B | p (exact McNemar) |", "|---|---|---|---|---|---|---|"]
    for cell in [*cells, pooled(cells)]:
        name = f"**{cell.env_id}**" if cell.env_id == "all tasks" else cell.env_id
        lines.append(f"| {name} | {cell.episodes} | {cell.a / cell.episodes:.0%} ({cell.a}) | "
                     f"{cell.b / cell.episodes:.0%} ({cell.b}) | {cell.only_a} | {cell.only_b} | {cell.p_value:.3g} |")
    return "\n".join(lines) + "\n"


__all__ = ["PairedCell", "load_results", "paired_cells", "pooled", "render_comparison"]
