"""MIKASA-Robo-VLA's RememberColor3/5/9-VLA-v0 as sb3-memret tasks: the cue's colour must be remembered.

The envs are MIKASA's own (``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``, its
``CurriculumPhaseNoopActionWrapper`` (actions are no-ops during the cue and delay phases), 128x128
cameras, the ``normalized_dense`` reward, success counted once per episode, evaluation at seeds
4242424242 + i.

**Episode:** the cue cube (one of N colours) is shown alone at the table centre for 1-5 steps, all
cubes are hidden for 1-5 steps, then the N cubes reappear, shuffled, and the robot must touch the
one of the cue's colour and hold still; episodes last 25 steps.

**Randomisations** (MIKASA's): the cue colour, uniform over N; the cue and delay lengths; the
cubes' positions; the arm's initial joints.

**Success:** MIKASA's: the TCP within 5 cm of the cue-coloured cube and the robot static, at any step.

**-Long variants** (``RememberColor3/5/9-Long-VLA-v0``): MIKASA's 600-step versions, registered with the same
class: a cue of 10-100 steps (5 and 9: 100), a delay of 50-450, and no no-op wrapper (MIKASA's wrapper table
gives them none), so the arm may move in every phase; the expert waits at its ready pose until every cube is in
sight (MIKASA's success is not gated on the phase: touching the cue itself would count).

The writer sees every control step: it reads the cue's colour from the base camera's pixels
(``read_cue_colour``) and writes ``the cue cube was {colour}.``; the bank's decoys are worded
alike about other things. The controller sees ``ControllerObservation`` only (never
``oracle_info``), so the colour reaches it only through its prompt.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from sb3_memret.memory.schema import MemoryType
from sb3_memret.tasks.mikasa.core.cue_task import EVAL_SEED, MikasaCueTask, with_long
from sb3_memret.tasks.mikasa.core.touch_expert import CUE_FACT, INSTRUCTION, PROMPT_TEMPLATE
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES, ControllerObservation, read_cue_colour

CUE_ENTITY = "cue cube"
CUE_KEY = (MemoryType.OTHER, CUE_ENTITY, "was")


class RememberColorTask(MikasaCueTask):
    """MIKASA-Robo-VLA's RememberColor{3,5,9}-VLA-v0: touch the cube of the colour shown once, earlier."""

    field, detector_key, truth_attribute = "colour", "cube", "true_color_indices"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, "was", CUE_FACT
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, COLOUR_NAMES
    observation_wrapper: ClassVar = ControllerObservation

    def __init__(self, env_id: str = "RememberColor3-VLA-v0"):
        colours = with_long({f"RememberColor{n}-VLA-v0": n for n in (3, 5, 9)})
        if env_id not in colours:
            raise ValueError(f"unknown RememberColor task {env_id!r}; expected one of {sorted(colours)}")
        super().__init__(env_id, colours[env_id])

    @property
    def n_colours(self) -> int:
        return self.n_words

    @property
    def colours(self) -> tuple[str, ...]:
        return self.words

    def read_cue(self, rgb: np.ndarray) -> str | None:
        return read_cue_colour(rgb, self.n_colours)


__all__ = ["CUE_ENTITY", "CUE_KEY", "EVAL_SEED", "RememberColorTask"]
