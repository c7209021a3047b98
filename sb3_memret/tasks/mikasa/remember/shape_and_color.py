"""MIKASA-Robo-VLA's RememberShapeAndColor3x2/3x3/5x3-VLA-v0 as sb3-memret tasks: the cue's shape and colour
must both be remembered.

The envs are MIKASA's own (``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``, its
``CurriculumPhaseNoopActionWrapper`` (actions are no-ops during the cue and delay phases), 128x128 cameras,
the ``normalized_dense`` reward, success counted once per episode, evaluation at seeds 4242424242 + i.

**Episode:** MIKASA's objects are every colour of red, lime and blue on each of the first shapes of cube,
sphere, t shape, cross, torus, in that order (3x2: a red, a lime and a blue cube and sphere, 6 objects; 3x3:
9, with the t shapes; 5x3: 15). The cue object is shown alone at the table centre for 1-5 steps, every
object is hidden for 1-5 steps, then all reappear, shuffled along an arc 30 cm around a point behind the
table centre, and the robot must touch the one of the cue's shape *and* colour (others share one of the
two) and hold still; episodes last 25 steps.

**Randomisations** (MIKASA's): the cue object, uniform over all; the cue and delay lengths; which object
stands where, and a jitter of about 1 cm; the arm's initial joints.

**Success:** MIKASA's: the TCP within 5 cm of the cue object's centre and the robot static, at any step.

**-Long variants** (``RememberShapeAndColor3x2/3x3/5x3-Long-VLA-v0``): MIKASA's 600-step versions, registered
with the same class: a cue of 10-100 steps, a delay of 50-450, and no no-op wrapper (MIKASA's wrapper table gives
them none), so the arm may move in every phase; the expert waits at its ready pose until every object is in sight
(MIKASA's success is not gated on the phase: touching the cue itself would count).

The writer sees every control step: it reads the cue's shape (``read_cue_shape``: the silhouette, the same
in every colour) and its colour (``read_cue_colour``) from the base camera's pixels and writes one fact naming
both, ``the cue object was a red cube.``; the bank's decoys are worded alike about other things (``the key
was a blue sphere.``). The controller sees ``ObjectControllerObservation`` only (never ``oracle_info``), so the
object reaches it only through its prompt.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from sb3_memret.memory.schema import MemoryType
from sb3_memret.controllers.prompts import PromptTemplate, build_prompt
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask, with_long
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES, DetectorObservation, read_cue_colour
from sb3_memret.tasks.mikasa.core.shape_perception import read_cue_shape

# MIKASA's RememberShapeAndColorVLABaseEnv.BASE_SHAPES and COLOR_PALETTE, in order (worded as prompts word them).
SHAPES: tuple[str, ...] = ("cube", "sphere", "t shape", "cross", "torus")
COLOURS: tuple[str, ...] = COLOUR_NAMES[:3]  # red, lime, blue
# Object i is shape i // 3 in colour i % 3: MIKASA's shape_color_dict, whose first N objects an env of N uses.
OBJECTS: tuple[str, ...] = tuple(f"{colour} {shape}" for shape in SHAPES for colour in COLOURS)
OBJECT_TASKS = with_long({"RememberShapeAndColor3x2-VLA-v0": 6, "RememberShapeAndColor3x3-VLA-v0": 9,
                          "RememberShapeAndColor5x3-VLA-v0": 15})

CUE_ENTITY = "cue object"
CUE_RELATION = "was_a"  # linearised "was a": "the cue object was a red cube."
CUE_KEY = (MemoryType.OTHER, CUE_ENTITY, CUE_RELATION)
# MIKASA's LANGUAGE_INSTRUCTION in the prompt contract's form (lowercase; it parses as is).
INSTRUCTION = "observe the object's shape and color, wait, then touch the object of the same shape and color."
# One field for colour and shape together ("red t shape"): two word fields side by side would not parse apart.
FACT_TEMPLATE = "the {entity} was a {object}."
CUE_FACT = "the cue object was a {object}."
PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(FACT_TEMPLATE,))


def object_prompt(word: str | None) -> str:
    """The controller's prompt: the instruction, plus the cue fact when ``word`` ("red cube") is given."""
    facts = [] if word is None else [CUE_FACT.format(object=word)]
    return build_prompt(INSTRUCTION, facts, PROMPT_TEMPLATE)


def read_cue_object(rgb: np.ndarray, n_objects: int) -> str | None:
    """The cue's colour and shape ("red cube") in one base-camera frame, among the first ``n_objects`` of
    ``OBJECTS``; None when no cue shows alone, or its shape or colour reads as none in play."""
    if not 1 <= n_objects <= len(OBJECTS):
        raise ValueError(f"n_objects must be in 1..{len(OBJECTS)}, got {n_objects}")
    in_play = OBJECTS[:n_objects]
    shapes = tuple(dict.fromkeys(SHAPES[i // len(COLOURS)] for i in range(n_objects)))
    shape = read_cue_shape(rgb, shapes)
    colour = read_cue_colour(rgb, len(COLOURS)) if shape is not None else None
    word = None if colour is None else f"{colour} {shape}"
    return word if word in in_play else None


def _objects(base: Any) -> list[Any]:
    return [base.shape_actors[i] for i in sorted(base.shape_actors)]


class ObjectControllerObservation(DetectorObservation):
    """A RememberShapeAndColor observation cut to a controller's view: ``extra/object_positions`` (B, n, 3) and
    ``extra/object_visible`` (B, n) by MIKASA's object index, as a detector of coloured shapes would report them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, _objects, "object")


class RememberShapeAndColorTask(MikasaCueTask):
    """MIKASA-Robo-VLA's RememberShapeAndColor{3x2,3x3,5x3}-VLA-v0: touch the object of the shape and colour shown
    once, earlier."""

    field, detector_key, truth_attribute = "object", "object", "true_shape_indices"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, CUE_RELATION, CUE_FACT
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, OBJECTS
    observation_wrapper: ClassVar = ObjectControllerObservation

    def __init__(self, env_id: str = "RememberShapeAndColor3x2-VLA-v0"):
        if env_id not in OBJECT_TASKS:
            raise ValueError(f"unknown RememberShapeAndColor task {env_id!r}; expected one of {sorted(OBJECT_TASKS)}")
        super().__init__(env_id, OBJECT_TASKS[env_id])

    def read_cue(self, rgb: np.ndarray) -> str | None:
        return read_cue_object(rgb, self.n_words)


__all__ = ["COLOURS", "CUE_ENTITY", "CUE_FACT", "CUE_KEY", "FACT_TEMPLATE", "INSTRUCTION", "OBJECTS",
           "ObjectControllerObservation", "PROMPT_TEMPLATE", "RememberShapeAndColorTask", "SHAPES", "object_prompt",
           "read_cue_object"]
