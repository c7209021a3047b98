"""The drawer's controller ablations (the seed paper's Tables 1-3), tables of ``sb3_memret.analysis.ablations``.

- ``replan``: oracle memory, success per layer for each replan interval (Table 1).
- ``prompt``: correct/wrong object word x correct/wrong layer, plus the bare prompt, with the
  cube in one layer (Table 2).
- ``memcount``: zero, one (oracle) and two (oracle + another true fact) memories, per layer
  (Table 3).
- ``wording``: the oracle memory reworded in ways no training prompt was, per layer. Its cells
  waive the prompt contract, which every other command enforces: that is what it measures.
"""

from __future__ import annotations

from typing import Sequence

from sb3_memret.tasks.ablations import OVERALL, AblationBuilder, AblationSpec, Cell
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks.drawer.cabinet import LAYERS, check_layer
from sb3_memret.tasks.drawer.prompts import HOLDING_NOTHING_TEXT, INSTRUCTION, TEMPLATE, location_text

REPLAN_INTERVALS: tuple[int, ...] = (5, 8, 10, 12, 16, 20, 24, 28, 32)
WRONG_OBJECT = "key"


def _at(layer: int) -> dict[str, int]:
    """The reset options that hide the cube in ``layer``."""
    return {"target_layer": layer}


def _layer_column(layer: int) -> str:
    return f"layer {layer}"


def replan_ablation(intervals: Sequence[int] = REPLAN_INTERVALS) -> AblationSpec:
    """Oracle memory; success per layer for each replan interval."""
    if not intervals or any(i < 1 for i in intervals):
        raise ValueError(f"replan intervals must be positive integers, got {list(intervals)}")
    rows = tuple(str(i) for i in intervals)
    cells = tuple(Cell(str(i), _layer_column(layer), build_prompt(INSTRUCTION, [location_text("cube", layer)], TEMPLATE),
                       _at(layer), i) for i in intervals for layer in LAYERS)
    return AblationSpec("replan", "Replan interval: success with the oracle memory", "replan steps", rows,
                        (*map(_layer_column, LAYERS), OVERALL), cells, pooled_column=OVERALL)


def prompt_ablation(layer: int = 2, replan_every: int | None = None) -> AblationSpec:
    """The cube in ``layer``; correct/wrong object word x correct/wrong layer, and the bare prompt."""
    check_layer(layer)
    wrong_layer = layer % len(LAYERS) + 1
    correct_word, wrong_word = "correct object word (cube)", f"wrong object word ({WRONG_OBJECT})"
    none_row = "no-memory prompt"
    cells = []
    for row, entity in ((correct_word, "cube"), (wrong_word, WRONG_OBJECT)):
        for column, named in (("correct layer", layer), ("wrong layer", wrong_layer)):
            cells.append(Cell(row, column, build_prompt(INSTRUCTION, [location_text(entity, named)], TEMPLATE), _at(layer),
                              replan_every))
    cells.append(Cell(none_row, "wrong layer", build_prompt(INSTRUCTION, [], TEMPLATE), _at(layer), replan_every))
    return AblationSpec("prompt", f"Prompt ablation: cube in drawer layer {layer}", "prompt condition",
                        (correct_word, wrong_word, none_row), ("correct layer", "wrong layer"), tuple(cells))


def memcount_ablation(replan_every: int | None = None) -> AblationSpec:
    """Zero, one (oracle) and two (oracle + 'the robot is holding nothing.', true at the start) memories."""
    rows = {"no memory (bare prompt)": lambda layer: [],
            "one memory (oracle)": lambda layer: [location_text("cube", layer)],
            "two memories (oracle + true)": lambda layer: [location_text("cube", layer), HOLDING_NOTHING_TEXT]}
    cells = tuple(Cell(row, _layer_column(layer), build_prompt(INSTRUCTION, memories(layer), TEMPLATE), _at(layer), replan_every)
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


def wording_ablation(replan_every: int | None = None, wordings: Sequence[str] = WORDINGS) -> AblationSpec:
    """The oracle memory in each wording, per layer; prompts are not checked against the template."""
    rows = tuple(w.replace("{layer}", "L").replace("{ordinal}", "N-th") for w in wordings)
    cells = tuple(
        Cell(row, _layer_column(layer),
             f"{INSTRUCTION} {wording.format(layer=layer, ordinal=ORDINALS[layer])}", _at(layer), replan_every,
             check_prompt=False)
        for row, wording in zip(rows, wordings) for layer in LAYERS)
    return AblationSpec("wording", "Memory wording: success with the oracle memory reworded", "memory sentence", rows,
                        (*map(_layer_column, LAYERS), OVERALL), cells, pooled_column=OVERALL)


ABLATIONS: dict[str, AblationBuilder] = {
    "replan": lambda options: replan_ablation(options.intervals or REPLAN_INTERVALS),
    "prompt": lambda options: prompt_ablation(_layer(options.group), options.replan_every),
    "memcount": lambda options: memcount_ablation(options.replan_every),
    "wording": lambda options: wording_ablation(options.replan_every),
}


def _layer(group: str | None) -> int:
    """The cube's layer a command names as the episodes' group (the prompt table's; layer 2 when none)."""
    if group is None:
        return 2
    if not group.isdigit() or int(group) not in LAYERS:
        raise ValueError(f"the prompt ablation's group is the cube's drawer layer, one of {list(LAYERS)}; got {group!r}")
    return int(group)


__all__ = ["ABLATIONS", "REPLAN_INTERVALS", "WORDINGS", "memcount_ablation", "prompt_ablation", "replan_ablation",
           "wording_ablation"]
