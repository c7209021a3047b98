"""What a controller ablation table is (the seed paper's Tables 1-3): its cells, each a prompt, the task's reset options
(which episode it plays: the drawer's cube layer) and a replan interval. A task names the tables it defines
(``Task.ablations``); ``sb3_memret.analysis.ablations`` plays them."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

OVERALL = "overall"


@dataclass(frozen=True)
class AblationOptions:
    """What a command may set of a task's ablation tables: the replan intervals of a table that varies them, the
    group its episodes play (the drawer: the cube's layer) and the replan interval of the others (None: the task's
    defaults)."""

    intervals: tuple[int, ...] | None = None
    group: str | None = None
    replan_every: int | None = None


#: a task's ablation tables by name, each built from the options a command sets (``Task.ablations``)
AblationBuilder = Callable[[AblationOptions], "AblationSpec"]


@dataclass(frozen=True)
class Cell:
    """One table cell: the episodes' prompt, the task's reset options and the replan interval (None: the task's)."""

    row: str
    column: str
    prompt: str
    reset_options: Mapping[str, Any] = field(default_factory=dict)
    replan_every: int | None = None
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


__all__ = ["AblationBuilder", "AblationOptions", "AblationSpec", "Cell", "OVERALL"]
