"""The battery checklist in words: one fact that carries every check made so far, and its parse.

``the battery check found slot 1 dead and slot 3 working.``: the tray slots (MIKASA's battery order, from 1) whose
battery went through a complete check (into the socket, the button pressed to confirm), each with what the lamp
said. One fact carries the whole list, replaced in place as it grows, so a controller that takes one memory at a
time (K = 1) gets all of it, as FindImposter's set fact does; decoys are worded alike about other things
(``the fuse check found slot 2 working.``).
"""

from __future__ import annotations

import re
from typing import Mapping

from sb3_memret.controllers.prompts import ParsedPrompt

CHECK_ENTITY, CHECK_RELATION = "battery check", "found"
FIELD = "checklist"
FACT_TEMPLATE = "the {entity} found {checklist}."
WORKING, DEAD = "working", "dead"
_ITEM = rf"slot [0-9]+ (?:{WORKING}|{DEAD})"
CHECKLIST_PATTERN = rf"{_ITEM}(?: and {_ITEM})*"
_ITEM_RE = re.compile(rf"slot ([0-9]+) ({WORKING}|{DEAD})")

Checklist = Mapping[int, bool]  # slot (from 1) -> whether its battery lit the lamp


def checklist_value(checks: Checklist) -> str:
    """``slot 1 dead and slot 3 working``: the checks in slot order; refused when empty (no fact says nothing)."""
    if not checks:
        raise ValueError("an empty checklist has no wording: write no fact until a check is complete")
    bad = [slot for slot in checks if not isinstance(slot, int) or slot < 1]
    if bad:
        raise ValueError(f"slots are whole numbers from 1, got {bad}")
    return " and ".join(f"slot {slot} {WORKING if checks[slot] else DEAD}" for slot in sorted(checks))


def checklist_fact(checks: Checklist) -> str:
    """The battery check's fact for ``checks``."""
    return FACT_TEMPLATE.format(entity=CHECK_ENTITY, checklist=checklist_value(checks))


def parse_checklist(value: str) -> dict[int, bool]:
    """The checks a checklist value names (``checklist_value``'s inverse); a slot named twice keeps its last word."""
    if not re.fullmatch(CHECKLIST_PATTERN, value):
        raise ValueError(f"{value!r} is not a checklist; expected e.g. 'slot 1 dead and slot 3 working'")
    return {int(slot): word == WORKING for slot, word in _ITEM_RE.findall(value)}


def stated_checklist(parsed: ParsedPrompt) -> dict[int, bool]:
    """The checklist of the prompt's first fact that carries one (whatever it is about), or none."""
    value = parsed.field(FIELD)
    return {} if value is None else parse_checklist(value)


__all__ = ["CHECKLIST_PATTERN", "CHECK_ENTITY", "CHECK_RELATION", "Checklist", "DEAD", "FACT_TEMPLATE", "FIELD",
           "WORKING", "checklist_fact", "checklist_value", "parse_checklist", "stated_checklist"]
