"""MIKASA-Robo-VLA's colour-cue tasks as sb3-memret tasks: BunchOfColors, SeqOfColors and ChainOfColors 3/5/7 and
their -Long variants (``variants``): several colours must reach the controller's prompt, so the retriever picks
K > 1 memories.

The env is MIKASA's own (``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``, 128x128 cameras, the
``normalized_dense`` reward, success counted once per episode, evaluation at seeds 4242424242 + i. MIKASA's wrapper
table (``apply_mikasa_vla_wrappers``) gives these tasks no ``CurriculumPhaseNoopActionWrapper``: actions act in
every phase.

**Episode:** 3, 5 or 7 of the 9 colours (red, lime, blue, yellow, magenta, cyan, maroon, olive, teal), drawn without
replacement, are shown: one at a time (Seq, Chain), each as one cube alone at the table centre for the same 1-5
steps (-Long: 10-100), or together (Bunch), on an arc round the table centre, for 1-5 steps (-Long: 10-100); all
cubes are hidden for 1-5 steps (-Long: 50-400); then the 9 cubes reappear, shuffled along an arc round the table,
with the centre button (a dark base and a red cap) in front of them; the robot must touch the cued cubes, then
press the button and lift. Episodes last MIKASA's 400 steps (-Long: Bunch 700; Seq and Chain 800, 1000, 1200 for
3, 5, 7); MIKASA masks success out of ``terminated``, so an episode never ends early.

**Randomisations** (MIKASA's): the cued colours (ordered for a sequence); the cue's item length and the delay; which
arc position each colour takes, with a jitter of ~1 cm (and >= 6 cm between cubes); the arm's initial joints. The
button stands at the cubes' mean position, 4 cm toward the robot.

**Success:** MIKASA's (``evaluate``), at any step: every cued cube touched, no other cube touched, no cube pushed
more than 6 cm, the button pressed after the last touch (the TCP within 2.5 cm of the cap's top and 6.5 cm of its
axis, then lifted 8.5 cm) and the robot static; for Seq and Chain the touches in the cue's order (SeqOfColors'
docstring and instruction say "in any order", but its ``wrong_order_touched`` compares the k-th distinct cube
touched with the k-th cue item, and refuses the press otherwise). A touch: the TCP within 2 cm of the point 2.5 cm
above the cube's centre, arm static (every joint < 0.2 rad/s), in the manipulation phase.

**Facts** (``writer``): one per cue item, worded with its ordinal, ``the first cue cube was red.``, ``the second cue
cube was blue.``: a sequence's in the cue's order, a bunch's in palette order. Decoys are worded alike about other
things (``the key was red.``). ``Episode.true_facts`` lists the items; a prompt needs all of them (one missing: the
expert touches out of order, leaves a cube untouched, or never presses).

The writer sees every control step of the cue: it reads a sequence's colour from the base camera's pixels
(``read_cue_colour``), a bunch's colours from its blobs (``read_cue_set``). The controller sees
``SeqControllerObservation`` only (never ``oracle_info``), so the cue reaches it only through its prompt.

**Progress as memory**: nothing in sight changes when a cube is touched, so a controller that reads only the current
frame and its prompt cannot tell which cubes it has touched. The writer then also writes what has been done, as
TASK_PROGRESS facts (``the red cube was touched.``, ``the button was pressed.``), from the base camera's cube layout
(read through its shipped calibration) and the arm's own sensors (``writer`` says how). Its expert is the stateless
``SequenceTouchController(progress_from="prompt")``, which learns what it has done from those facts alone.
``SeqOfColorsTask(env_id, progress=False)`` is the task without progress facts, whose expert keeps track of its own
touches (state across calls).
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import PromptTemplate, build_prompt
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.tasks.base import EnvFrame, Episode
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.layout_perception import read_cue_set
from sb3_memret.tasks.mikasa.core.perception import (COLOUR_NAMES, ControllerObservation, read_cue_colour,
                                                     stack_positions)
from sb3_memret.tasks.mikasa.core.sequence_expert import PRESSED_FACT, TOUCHED_FACT, SequenceTouchController
from sb3_memret.tasks.mikasa.core.touch_expert import FACT_TEMPLATE
from sb3_memret.tasks.mikasa.seq_of_colors.variants import ANY_ORDER, ColourCueVariant, variant
from sb3_memret.tasks.mikasa.seq_of_colors.writer import (CUE_ENTITY, CUE_FACT, N_COLOURS, PROGRESS_WORDINGS,
                                                          SequenceWriter, in_palette_order, item_entity, item_key,
                                                          sequence_facts)

# SeqOfColors' (and BunchOfColors') instruction in the prompt contract's form (lowercase; it parses as is). Its "in
# any order" is MIKASA's wording; for SeqOfColors MIKASA's success checks the order (see the module docstring).
INSTRUCTION = ANY_ORDER
EPISODE_STEPS = 400  # the 400-step variants'; each variant's own in ``variants``


def prompt_template(instruction: str = INSTRUCTION, progress: bool = False) -> PromptTemplate:
    """The prompt contract of a colour-cue task: its instruction and the cue's facts, with progress facts first
    when ``progress`` (so ``the red cube was touched.`` is not read as FACT_TEMPLATE's colour "touched")."""
    facts = (TOUCHED_FACT, PRESSED_FACT, FACT_TEMPLATE) if progress else (FACT_TEMPLATE,)
    return PromptTemplate(instructions=(instruction,), fact_templates=facts)


PROMPT_TEMPLATE = prompt_template()
PROGRESS_PROMPT_TEMPLATE = prompt_template(progress=True)


def sequence_prompt(colours: tuple[str, ...] | list[str] | None, instruction: str = INSTRUCTION) -> str:
    """The controller's prompt: the instruction, plus one fact per cue item when ``colours`` is given."""
    return build_prompt(instruction, sequence_facts(colours or []), prompt_template(instruction))


def sequence_expert(chunk_len: int = 8, progress_from: str = "observation",
                    instruction: str = INSTRUCTION) -> SequenceTouchController:
    """The scripted expert: touches the prompt's colours in order, presses the button; holds still without one.
    ``progress_from="prompt"``: stateless, it learns what it has done from its prompt's progress facts."""
    return SequenceTouchController(prompt_template(instruction, progress_from == "prompt"), chunk_len,
                                   progress_from=progress_from)


class SeqControllerObservation(ControllerObservation):
    """``ControllerObservation`` plus what a detector sees of the centre button: ``extra/button_position``
    (B, 3), the centre of its (fixed) base; the button is in sight all episode."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        batch = int(getattr(env.unwrapped, "num_envs", 1))
        self.observation_space["extra"]["button_position"] = spaces.Box(-np.inf, np.inf, (batch, 3), np.float32)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        out["extra"]["button_position"] = stack_positions([self.env.unwrapped.button_base.pose.p],
                                                          like=obs["extra"]["tcp_pose"])[:, 0]
        return out


class SeqOfColorsTask(MikasaCueTask):
    """MIKASA-Robo-VLA's colour-cue tasks (``variants.VARIANTS``: BunchOfColors, SeqOfColors, ChainOfColors 3/5/7 and
    -Long): touch the cubes of the colours shown earlier (in their order, for a sequence), then press the centre
    button."""

    field, detector_key, truth_attribute = "colour", "cube", "true_color_indices"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, "was", CUE_FACT
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, COLOUR_NAMES
    observation_wrapper: ClassVar = SeqControllerObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives these tasks none: actions act in every phase
    max_control_steps = EPISODE_STEPS
    ends_at_success = True  # MIKASA masks success out of terminated; its success once is over by then
    success_reward = 1.0  # normalized_dense pays 400 / 400 at every step it reads success

    def __init__(self, env_id: str = "SeqOfColors3-VLA-v0", progress: bool = True):
        self.variant: ColourCueVariant = variant(env_id)
        super().__init__(env_id, N_COLOURS)
        self.n_items, self.progress = self.variant.n_items, progress
        self.max_control_steps = self.variant.episode_steps
        self.noop_before_manipulation = False
        self.instruction_text = self.variant.instruction
        self.template = prompt_template(self.variant.instruction, progress)
        self.frames_read_images = progress  # the progress writer reads the cube layout from the decisions' images
        if progress:
            self.wordings = PROGRESS_WORDINGS

    @property
    def colours(self) -> tuple[str, ...]:
        return self.words

    def read_cue(self, rgb: np.ndarray) -> str | tuple[str, ...] | None:
        """A sequence's item (one colour), or a bunch's colours (left to right in the image), or None."""
        return read_cue_set(rgb, N_COLOURS) if self.variant.together else read_cue_colour(rgb, N_COLOURS)

    def perception_window(self, env: gym.Env) -> int | None:
        """The longest cue MIKASA's env can draw, and one step more: a bunch's ``CUE_PHASE_STEPS``, a sequence's
        ``CUE_STEP_DURATION`` for each of its items."""
        base = env.unwrapped
        if self.variant.together:
            return super().perception_window(env)
        duration = getattr(base, "CUE_STEP_DURATION", None)
        return None if duration is None else int(max(duration)) * self.n_items + 1

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs = to_numpy(obs)
        base = env.unwrapped  # privileged: for metrics only
        success = as_numpy(info["success"]).reshape(-1)
        n = len(success)
        cued = as_numpy(base.true_color_indices).reshape(n, -1)
        if self.variant.together:
            lengths, length_key = as_numpy(base.cue_steps_per_env).reshape(-1), "cue_steps"
        else:
            lengths, length_key = as_numpy(base.cue_step_duration_per_env).reshape(-1), "cue_step_duration"
        states = []
        for i in range(n):
            colours = tuple(self.colours[int(c)] for c in cued[i])
            states.append({"colours": in_palette_order(colours) if self.variant.together else colours,
                           length_key: int(lengths[i])})
        if self.progress:
            touched = self._touched(base, n)
            # a press begun (MIKASA's pending one) or counted: the writer writes it at the press's bottom too
            pressed = as_numpy(base.pending_press).reshape(-1) | (as_numpy(base.button_press_count).reshape(-1) > 0)
            for i, state in enumerate(states):
                # what MIKASA counted done (privileged: the fixed conditions' progress facts)
                state["touched"] = touched[i]
                state["pressed"] = bool(pressed[i])
        return [EnvFrame(select_obs(obs, i), states[i], None, bool(success[i])) for i in range(n)]

    def _touched(self, base: Any, n: int) -> list[tuple[str, ...]]:
        """The colours MIKASA counted touched in each env: in touch order where it keeps one (Seq, Chain), else in
        palette order (Bunch keeps a mask)."""
        if hasattr(base, "touched_cubes_idx"):
            order = as_numpy(base.touched_cubes_idx).reshape(n, -1)
            return [tuple(self.colours[int(c)] for c in row if c >= 0) for row in order]
        mask = as_numpy(base.touched_cubes).reshape(n, -1).astype(bool)
        return [tuple(self.colours[int(c)] for c in np.flatnonzero(row)) for row in mask]

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> SequenceWriter:
        return SequenceWriter(self.n_items, self.progress, together=self.variant.together)

    def episode(self, frame: EnvFrame) -> Episode:
        colours = tuple(frame.state["colours"])
        facts = tuple((item_key(k), c) for k, c in enumerate(colours))
        details = {"cue_colours": " ".join(colours)}
        details.update({key: frame.state[key] for key in ("cue_step_duration", "cue_steps") if key in frame.state})
        return Episode("cue cubes", colours[0], facts, details)

    def event_decoy(self, rng: np.random.Generator, now: int, seeding: SeedingConfig) -> MemoryEntry:
        """Another thing's colour seen in passing (``the key was teal.``), worded as the reset's decoys are."""
        thing = str(rng.choice(sorted(set(seeding.vocabulary))))
        return MemoryEntry.create(MemoryType.OTHER, thing, self.cue_relation, str(rng.choice(self.words)), now)

    def timescale(self, entry: MemoryEntry) -> str:
        """The cue's items hold for the episode; another thing's colour (a decoy, an event) only at the moment."""
        if entry.type == MemoryType.OTHER and not entry.entity.endswith(CUE_ENTITY):
            return "now"
        return super().timescale(entry)

    # ------------------------------------------------------------ prompts and controllers
    @staticmethod
    def sequence(episode: Episode) -> tuple[str, ...]:
        return tuple(value for _, value in episode.true_facts)

    def oracle_facts(self, episode: Episode) -> list[str]:
        return sequence_facts(self.sequence(episode))

    def progress_facts(self, frame: EnvFrame) -> list[str]:
        """With progress: ``the red cube was touched.`` for each cube MIKASA counted touched, in touch order, then
        ``the button was pressed.`` once a press began (as the writer writes it, at the press's bottom)."""
        if not self.progress:
            return []
        touched = [TOUCHED_FACT.format(touched=colour) for colour in frame.state["touched"]]
        return touched + ([PRESSED_FACT] if frame.state["pressed"] else [])

    def wrong_facts(self, episode: Episode) -> list[str]:
        """The same ordinals, naming first the colours that were not cued (in palette order), then, where fewer than
        the items are left (7 of 9 cued), the cued ones: every wrong prompt sends the expert to a cube not cued."""
        cued = self.sequence(episode)
        others = [c for c in self.colours if c not in cued]
        return sequence_facts((others + list(cued))[: len(cued)])

    def expert(self) -> SequenceTouchController:
        return sequence_expert(progress_from="prompt" if self.progress else "observation",
                               instruction=self.instruction_text)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.with_state_extra(super().demo_features(with_images), "button")

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.append_state(super().demo_frame(obs, with_images), obs["extra"]["button_position"])


__all__ = ["CUE_FACT", "EPISODE_STEPS", "INSTRUCTION", "PROGRESS_PROMPT_TEMPLATE", "PROGRESS_WORDINGS",
           "PROMPT_TEMPLATE", "SeqControllerObservation", "SeqOfColorsTask", "SequenceWriter", "item_entity",
           "item_key", "prompt_template", "sequence_expert", "sequence_facts", "sequence_prompt"]
