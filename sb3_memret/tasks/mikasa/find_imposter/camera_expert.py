"""FindImposterColor's touch expert on what MIKASA's harness gives a policy alone: a protocol entry, not an upper
bound.

``ImposterTouchController`` reads the cubes' places from a simulated detector and the arm's joint velocities, so its
rows are a privileged upper bound. ``CameraImposterController`` touches the cube it chooses as that expert does (the
one colour no fact of its prompt names, once every cube is in sight; its ``chooser``) on the harness's inputs only:
the cubes' places from the base camera (``CubeLayout``: a frame that shows more cubes than the cue's N - 1 places
them, so never where the cue showed them) and the hand's motion dead-reckoned from its pose
(``CameraTouchController``, RememberColor's camera expert, whose motion it is).
"""

from __future__ import annotations

from typing import Sequence

from sb3_memret.controllers.prompts import ParsedPrompt
from sb3_memret.tasks.mikasa.core.carry_expert import REACH_X
from sb3_memret.tasks.mikasa.core.touch_expert import TouchGains
from sb3_memret.tasks.mikasa.find_imposter.task import ImposterTouchController
from sb3_memret.tasks.mikasa.remember.camera_expert import CameraTouchController


class CameraImposterController(CameraTouchController):
    """Touches the cube of the colour its prompt's facts do not name, reading only the base camera's image and the
    hand's pose. ``chooser``: the detector's expert of the task, which says which colour (``_chosen``); its
    vocabulary, template and default are this controller's. ``paced_every``: the control steps executed between its
    calls."""

    def __init__(self, chooser: ImposterTouchController, paced_every: int, chunk_len: int = 8):
        super().__init__(chooser.vocabulary, chooser.spec.prompt_template, paced_every, chunk_len,
                         gains=TouchGains(max_x=REACH_X), default=chooser.default, wait_for_all=True,
                         shown_at_once=len(chooser.vocabulary) - 1)
        self.chooser = chooser

    def _chosen(self, parsed: Sequence[ParsedPrompt]) -> list[str | None]:
        return self.chooser._chosen(parsed)


__all__ = ["CameraImposterController"]
