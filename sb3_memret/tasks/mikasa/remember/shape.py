"""MIKASA-Robo-VLA's RememberShape3/5/9-VLA-v0 as sb3-memret tasks: the cue's shape must be remembered.

The env is MIKASA's own (``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``, its
``CurriculumPhaseNoopActionWrapper`` (actions are no-ops during the cue and delay phases), 128x128
cameras, the ``normalized_dense`` reward, success counted once per episode, evaluation at seeds
4242424242 + i.

**Episode:** the cue object (one of the first N of MIKASA's shapes: cube, sphere, cylinder, then cross,
torus, then star, pyramid, t shape, crescent; all the same blue and 4-6 cm across) is shown alone at
the table centre for 1-5 steps, every object is hidden for 1-5 steps, then the N reappear, shuffled,
and the robot must touch the one of the cue's shape and hold still; episodes last 25 steps. Three
shapes stand along a row across the table (about 20 cm apart); five and nine along an arc 30 cm
around a point behind the table centre (12-19 cm apart).

**Randomisations** (MIKASA's): the cue shape, uniform over the N; the cue and delay lengths; the
objects' positions (which one stands where, and a jitter of about 1 cm); the arm's initial joints.

**Success:** MIKASA's: the TCP within 5 cm of the cue-shaped object's centre and the robot static,
at any step.

**-Long variants** (``RememberShape3/5/9-Long-VLA-v0``): MIKASA's 600-step versions, registered with the same
class: a cue of 10-100 steps, a delay of 50-450, and no no-op wrapper (MIKASA's wrapper table gives them none),
so the arm may move in every phase; the expert waits at its ready pose until every object is in sight (MIKASA's
success is not gated on the phase: touching the cue itself would count).

The writer sees every control step: it reads the cue's shape from the base camera's pixels
(``read_cue_shape``: its silhouette and shading) and writes ``the cue object was a {shape}.``; the
bank's decoys are worded alike about other things (``the key was a sphere.``). The controller sees
``ShapeControllerObservation`` only (never ``oracle_info``), so the shape reaches it only through
its prompt.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from sb3_memret.memory.schema import MemoryType
from sb3_memret.controllers.prompts import PromptTemplate, build_prompt
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask, with_long
from sb3_memret.tasks.mikasa.core.touch_expert import ScriptedTouchController
from sb3_memret.tasks.mikasa.core.shape_perception import SHAPE_NAMES, ShapeControllerObservation, read_cue_shape

CUE_ENTITY = "cue object"
CUE_RELATION = "was_a"  # linearised "was a": "the cue object was a cube."
CUE_KEY = (MemoryType.OTHER, CUE_ENTITY, CUE_RELATION)
# MIKASA's LANGUAGE_INSTRUCTION in the prompt contract's form (lowercase; it parses as is).
INSTRUCTION = "observe the object's shape, wait, then touch the object of the same shape."
# Like a finetuned VLA it follows the shape word whatever the fact is about: a decoy ("the key was a
# sphere.") misleads it as the wrong cue would, so retrieval has to pick the cue's fact.
FACT_TEMPLATE = "the {entity} was a {shape}."
CUE_FACT = "the cue object was a {shape}."
PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(FACT_TEMPLATE,))
SHAPE_TASKS = with_long({f"RememberShape{n}-VLA-v0": n for n in (3, 5, 9)})


def shape_prompt(shape: str | None) -> str:
    """The controller's prompt: the instruction, plus the cue fact when ``shape`` is given."""
    facts = [] if shape is None else [CUE_FACT.format(shape=shape)]
    return build_prompt(INSTRUCTION, facts, PROMPT_TEMPLATE)


def shape_expert(n_shapes: int = 3, chunk_len: int = 8) -> ScriptedTouchController:
    """The scripted expert: touches the object whose shape the prompt's fact names; holds still without one."""
    return ScriptedTouchController(chunk_len, vocabulary=SHAPE_NAMES[:n_shapes], field="shape",
                                   prompt_template=PROMPT_TEMPLATE, key="shape")


class RememberShapeTask(MikasaCueTask):
    """MIKASA-Robo-VLA's RememberShape{3,5,9}-VLA-v0: touch the object of the shape shown once, earlier."""

    field, detector_key, truth_attribute = "shape", "shape", "true_shape_indices"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, CUE_RELATION, CUE_FACT
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, SHAPE_NAMES
    observation_wrapper: ClassVar = ShapeControllerObservation

    def __init__(self, env_id: str = "RememberShape3-VLA-v0"):
        if env_id not in SHAPE_TASKS:
            raise ValueError(f"unknown RememberShape task {env_id!r}; expected one of {sorted(SHAPE_TASKS)}")
        super().__init__(env_id, SHAPE_TASKS[env_id])

    @property
    def n_shapes(self) -> int:
        return self.n_words

    @property
    def shapes(self) -> tuple[str, ...]:
        return self.words

    def read_cue(self, rgb: np.ndarray) -> str | None:
        return read_cue_shape(rgb, self.shapes)


__all__ = ["CUE_ENTITY", "CUE_FACT", "CUE_KEY", "FACT_TEMPLATE", "INSTRUCTION", "PROMPT_TEMPLATE", "RememberShapeTask",
           "shape_expert", "shape_prompt"]
