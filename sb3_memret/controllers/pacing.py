"""How many control steps of each action chunk run before the controller is asked again, checked against a
controller that measures its own motion over a fixed number of them (``paced_every``)."""

from __future__ import annotations

from typing import Any


def replan_interval(task: Any, replan_every: int | None, controller: Any, whose: str = "the") -> int:
    """``Task.replan_interval`` for ``controller``'s chunk length; a controller with ``paced_every`` (the steps it
    reads its hand's motion over, between two calls) refuses any other interval, naming both."""
    steps = task.replan_interval(replan_every, controller.spec.chunk_len, whose)
    paced = getattr(controller, "paced_every", None)
    if paced is not None and steps != paced:
        raise ValueError(f"{type(controller).__name__} measures its hand's motion over {paced} control steps between "
                         f"calls, but {steps} would run (replan_every); use replan_every {paced}, or build it with "
                         f"paced_every={steps}")
    return steps


__all__ = ["replan_interval"]
