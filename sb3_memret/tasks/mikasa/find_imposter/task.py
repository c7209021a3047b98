"""MIKASA-Robo-VLA's FindImposter tasks (memory type "Negative") as sb3-memret tasks: remember a *set* of objects
shown, then touch the one that was not in it.

FindImposterColor3/5/9-VLA-v0 (cubes of MIKASA's first N colours), FindImposterShape3/5/9-VLA-v0 (blue objects of
its first N shapes), FindImposterShapeAndColor3x2/3x3/5x3-VLA-v0 (a red, a lime and a blue object of each of its
first 2, 3 or 5 shapes). The envs are MIKASA's own, with its protocol: ``pd_ee_delta_pose``, its
``CurriculumPhaseNoopActionWrapper`` (actions are no-ops during the cue and delay phases), 128x128 cameras, the
``normalized_dense`` reward, success counted once per episode, evaluation at seeds 4242424242 + i.

**Episode** (MIKASA's env code): every object but one, the imposter, stands at a spread place (three along a row
across the table, more along an arc, 30 cm around a point behind the table centre, 45 cm for fifteen) for 1-5
steps; all are hidden for 1-5 steps; then all N, the imposter too, reappear at the same places shuffled among
them, and the robot must touch the imposter and hold still. Episodes last 25 steps (5x3: 40). Success counts in the
manipulation phase only.

**Randomisations** (MIKASA's): the imposter, uniform over the N; the places' order and a jitter of about 1 cm; the
cue and delay lengths; the arm's initial joints.

**Memory.** The writer reads the base camera at every control step (``imposter_perception.read_shown``: colours
from each object's top face, shapes by its shading against the task's exemplars seen at its place, each object a
different candidate) and, from the first frame that shows N - 1 objects, writes what the cue showed, in one of two
wordings (``wording``):

- ``"set"`` (the default): one fact naming the set, ``the shown cubes were red and lime.``, ``the shown objects
  were a cube and a cross.``; decoys are worded alike about other things (``the keys were red and blue.``);
- ``"each"``: one fact per object shown, ``the red cube was shown.``, all of which must reach the prompt (K = N - 1);
  decoys are worded alike about other things (``the key was shown.``).

The expert (``ImposterTouchController``) touches the object in sight whose word no fact of its prompt names, once
all N are in sight; with no fact it touches the first object (a guess: success at chance).

**Which wording** (``lab/2026-11-27-imposter-wordings/imposter_wordings.py``, the scripted expert standing in for a controller finetuned on
each wording, 10 episodes per cell at seeds 5000-5009): the expert follows both alike, episode for episode on
every task: oracle 10/10 with either wording everywhere (5x3 9/10 before its reach cap), written (the writer's
facts, no retriever) Color3/5/9 10/10, Shape3 10/10, Shape5 9/10, Shape9 7/10, ShapeAndColor3x2 10/10, 3x3 9/10,
5x3 9/10 with either. What differs is what a memory must retrieve: one fact (K = 1) against N - 1 of them (up to
14), so the single fact is the default.
"""

from __future__ import annotations

from typing import ClassVar, Mapping, Sequence

import numpy as np

from sb3_memret.memory.schema import Key, MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.carry_expert import REACH_X
from sb3_memret.tasks.mikasa.core.touch_expert import ScriptedTouchController, TouchGains
from sb3_memret.tasks.mikasa.find_imposter.perception import read_shown, task_exemplars
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES, ControllerObservation
from sb3_memret.tasks.mikasa.remember.shape_and_color import OBJECTS, ObjectControllerObservation
from sb3_memret.tasks.mikasa.core.shape_perception import SHAPE_NAMES, ShapeControllerObservation

WORDINGS = ("set", "each")
DEFAULT_WORDING = "set"
SHOWN = "shown"  # the facts' field that names what was shown: the set (``set``) or one object (``each``)
SET_RELATION, EACH_RELATION, EACH_VALUE = "were", "was", "shown"


def set_phrase(items: Sequence[str]) -> str:
    """``a``, ``a and b``, ``a and b and c``: words only (a prompt's fields hold lowercase words and spaces)."""
    return " and ".join(items)


def plural(noun: str) -> str:
    """The plural of a decoy noun (``key`` -> ``keys``, ``battery`` -> ``batteries``)."""
    return noun[:-1] + "ies" if noun.endswith("y") and noun[-2:-1] not in "aeiou" else noun + "s"


class ShownWriter:
    """Writes what the cue showed from the first control step whose frame showed a set (``perceive``: the words of
    the N - 1 objects in view): one fact naming the set, or one fact per object. Later frames change nothing (the
    choice phase may hide an object behind the arm and show N - 1 again); a reset frame starts a new episode."""

    def __init__(self, task: "FindImposterTask"):
        self.task = task
        relation = SET_RELATION if task.wording == "set" else EACH_RELATION
        self.relations = {SHOWN: (MemoryType.OTHER, relation)}
        self._written = False

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self._written = False
        for step, shown in frame.timed_percepts():
            if shown is not None and not self._written:
                self._written = True
                return [(step, {(SHOWN, entity): value for (_, entity, _), value in self.task.shown_facts(shown)})]
        return []


class ImposterTouchController(ScriptedTouchController):
    """Touches the object in sight whose word none of its prompt's facts names (``field`` holds one object's phrase
    or a set of them joined by ``and``; ``phrases`` maps each phrase to its word), once every candidate is in sight.
    Several unnamed: the first of them (a guess); none named, or all: ``default``, a guess. Its hand goes no farther
    than the arm reaches pointing down (``REACH_X``): fifteen objects stand up to x = 0.21 m, and commanding the
    hand beyond its reach stalls the arm short of it (2 of 20 oracle episodes of 5x3 failed so)."""

    def __init__(self, chunk_len: int = 8, gains: TouchGains | None = None, *, vocabulary: Sequence[str],
                 phrases: Mapping[str, str], field: str, prompt_template: PromptTemplate, key: str, default: str):
        super().__init__(chunk_len, gains or TouchGains(max_x=REACH_X), vocabulary=vocabulary, field=field,
                         prompt_template=prompt_template, key=key, default=default, wait_for_all=True)
        unknown = sorted(set(phrases.values()) - set(vocabulary))
        if unknown:
            raise ValueError(f"phrases name {unknown}, which are not in the vocabulary {list(vocabulary)}")
        self.phrases = dict(phrases)

    def named(self, parsed: ParsedPrompt) -> set[str]:
        """The words the prompt's facts name (phrases it does not know are ignored)."""
        words = set()
        for fact in parsed.facts:
            for key, value in fact.fields:
                if key == self.field:
                    items = (item.removeprefix("a ").removeprefix("an ") for item in value.split(" and "))
                    words |= {self.phrases[item] for item in items if item in self.phrases}
        return words

    def _chosen(self, parsed: Sequence[ParsedPrompt]) -> list[str | None]:
        chosen = []
        for prompt in parsed:
            named = self.named(prompt)
            unnamed = [w for w in self.vocabulary if w not in named]
            chosen.append(unnamed[0] if named and unnamed else self.default)
        return chosen


class FindImposterTask(MikasaCueTask):
    """A FindImposter task: its family's class attributes say what the objects are and how facts word them."""

    field = "imposter"
    #: MIKASA's env ids of the family and their object counts
    sizes: ClassVar[dict[str, int]]
    #: the set fact's entity (``shown cubes``)
    set_entity: ClassVar[str]
    #: the instruction, MIKASA's, lowercased
    instruction_text: ClassVar[str]
    #: whether objects differ in shape: the reader then matches shapes against the task's shipped exemplars
    reads_shapes: ClassVar[bool] = False
    long_steps: ClassVar[Mapping[str, int]] = {}  # env ids whose episodes last longer than 25 steps

    def __init__(self, env_id: str, wording: str = DEFAULT_WORDING):
        if env_id not in self.sizes:
            raise ValueError(f"unknown {type(self).__name__} env {env_id!r}; expected one of {sorted(self.sizes)}")
        if wording not in WORDINGS:
            raise ValueError(f"unknown wording {wording!r}; expected one of {list(WORDINGS)}")
        super().__init__(env_id, self.sizes[env_id])
        self.wording = wording
        self.max_control_steps = self.long_steps.get(env_id, self.max_control_steps)
        self._template = PromptTemplate((self.instruction_text,), (
            f"the {{entity}} {SET_RELATION} {{{SHOWN}}}." if wording == "set" else
            f"the {{{SHOWN}}} {EACH_RELATION} {EACH_VALUE}.",))

    # ------------------------------------------------------------ words
    def candidate(self, word: str) -> tuple[str | None, str | None]:
        """(colour, shape) of the object ``word`` names, for the reader (None: all objects share it)."""
        raise NotImplementedError

    def in_set(self, word: str) -> str:
        """How a set names the object: ``red`` (cubes), ``a cross``, ``a red cube``."""
        raise NotImplementedError

    def alone(self, word: str) -> str:
        """How a fact of its own names the object: ``red cube``, ``cross``."""
        raise NotImplementedError

    def shown_facts(self, shown: Sequence[str]) -> list[tuple[Key, str]]:
        """The (key, value) of the facts that say ``shown`` (words, in MIKASA's order) were shown."""
        ordered = [w for w in self.words if w in shown]
        if self.wording == "set":
            return [((MemoryType.OTHER, self.set_entity, SET_RELATION), set_phrase([self.in_set(w) for w in ordered]))]
        return [((MemoryType.OTHER, self.alone(w), EACH_RELATION), EACH_VALUE) for w in ordered]

    def _texts(self, shown: Sequence[str]) -> list[str]:
        return [MemoryEntry.create(key[0], key[1], key[2], value, 0).text for key, value in self.shown_facts(shown)]

    # ------------------------------------------------------------ perception and memory
    def read_cue(self, rgb: np.ndarray) -> tuple[str, ...] | None:
        """The words of the objects in view when they are N - 1 (the cue's count), each a different one."""
        exemplars = task_exemplars(self.name) if self.reads_shapes else None
        shown = read_shown(rgb, [self.candidate(w) for w in self.words], self.n_words - 1, exemplars)
        return None if shown is None else tuple(self.words[j] for j in shown)

    def writer(self, source: str = "seeded") -> ShownWriter:
        return ShownWriter(self)

    def episode(self, frame: EnvFrame) -> Episode:
        imposter = frame.state[self.field]
        shown = [w for w in self.words if w != imposter]
        return Episode(self.set_entity, imposter, tuple(self.shown_facts(shown)), {"imposter": imposter})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` facts worded as the cue's about other things: ``the keys were red and blue.``
        (a random set of N - 1), or ``the key was shown.``; the cue's facts come only from what the camera saw."""
        vocab = sorted(set(seeding.vocabulary))
        decoys = []
        for noun in rng.choice(vocab, size=seeding.location_decoys, replace=False):
            if self.wording == "set":
                shown = sorted(rng.choice(self.n_words, size=self.n_words - 1, replace=False))
                value = set_phrase([self.in_set(self.words[j]) for j in shown])
                decoys.append(MemoryEntry.create(MemoryType.OTHER, plural(str(noun)), SET_RELATION, value, 0))
            else:
                decoys.append(MemoryEntry.create(MemoryType.OTHER, str(noun), EACH_RELATION, EACH_VALUE, 0))
        return decoys

    # ------------------------------------------------------------ prompts and controllers
    @property
    def prompt_template(self) -> PromptTemplate:
        return self._template

    def oracle_facts(self, episode: Episode) -> list[str]:
        return self._texts([w for w in self.words if w != episode.group])

    def wrong_facts(self, episode: Episode) -> list[str]:
        """The set with the imposter in it instead of the object after it: that object is the one left unnamed."""
        left_out = self.words[(self.words.index(episode.group) + 1) % self.n_words]
        return self._texts([w for w in self.words if w != left_out])

    def expert(self) -> ImposterTouchController:
        phrases = {self.in_set(w).removeprefix("a ").removeprefix("an "): w for w in self.words}
        phrases |= {self.alone(w): w for w in self.words}
        return ImposterTouchController(vocabulary=self.words, phrases=phrases, field=SHOWN,
                                       prompt_template=self.prompt_template, key=self.detector_key,
                                       default=self.words[0])


class FindImposterColorTask(FindImposterTask):
    """FindImposterColor{3,5,9}-VLA-v0: cubes of MIKASA's first N colours; touch the one of the colour not shown."""

    sizes = {f"FindImposterColor{n}-VLA-v0": n for n in (3, 5, 9)}
    detector_key, truth_attribute, vocabulary = "cube", "imposter_key", COLOUR_NAMES
    set_entity = "shown cubes"
    instruction_text = "observe the cubes shown, wait, then touch the cube whose color was not present before."
    observation_wrapper: ClassVar = ControllerObservation

    def candidate(self, word: str) -> tuple[str | None, str | None]:
        return word, None

    def in_set(self, word: str) -> str:
        return word

    def alone(self, word: str) -> str:
        return f"{word} cube"


class FindImposterShapeTask(FindImposterTask):
    """FindImposterShape{3,5,9}-VLA-v0: blue objects of MIKASA's first N shapes; touch the one of the shape not
    shown."""

    sizes = {f"FindImposterShape{n}-VLA-v0": n for n in (3, 5, 9)}
    detector_key, truth_attribute, vocabulary = "shape", "imposter_key", SHAPE_NAMES
    set_entity = "shown objects"
    instruction_text = "observe the shapes shown, wait, then touch the object whose shape was not present before."
    observation_wrapper: ClassVar = ShapeControllerObservation
    reads_shapes = True

    def candidate(self, word: str) -> tuple[str | None, str | None]:
        return None, word

    def in_set(self, word: str) -> str:
        return f"a {word}"

    def alone(self, word: str) -> str:
        return word


class FindImposterShapeAndColorTask(FindImposterTask):
    """FindImposterShapeAndColor{3x2,3x3,5x3}-VLA-v0: a red, a lime and a blue object of each of MIKASA's first 2, 3
    or 5 shapes; touch the one whose shape and colour together were not shown."""

    sizes = {"FindImposterShapeAndColor3x2-VLA-v0": 6, "FindImposterShapeAndColor3x3-VLA-v0": 9,
             "FindImposterShapeAndColor5x3-VLA-v0": 15}
    long_steps = {"FindImposterShapeAndColor5x3-VLA-v0": 40}
    detector_key, truth_attribute, vocabulary = "object", "true_shape_indices", OBJECTS
    set_entity = "shown objects"
    instruction_text = ("observe the objects shown, wait, then touch the object whose shape and color combination "
                        "was not present before.")
    observation_wrapper: ClassVar = ObjectControllerObservation
    reads_shapes = True

    def candidate(self, word: str) -> tuple[str | None, str | None]:
        colour, shape = word.split(" ", 1)
        return colour, shape

    def in_set(self, word: str) -> str:
        return f"a {word}"

    def alone(self, word: str) -> str:
        return word


__all__ = ["DEFAULT_WORDING", "FindImposterColorTask", "FindImposterShapeAndColorTask", "FindImposterShapeTask",
           "FindImposterTask", "ImposterTouchController", "ShownWriter", "WORDINGS", "plural", "set_phrase"]
