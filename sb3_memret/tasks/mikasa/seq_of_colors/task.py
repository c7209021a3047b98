"""MIKASA-Robo-VLA's SeqOfColors3-VLA-v0 as an sb3-memret task: a sequence of cue colours must be remembered.

The memory-capacity task: several facts must reach the controller's prompt, so the retriever picks
K > 1 memories. The env is MIKASA's own (``mikasa-robo-suite``), with its protocol:
``pd_ee_delta_pose``, 128x128 cameras, the ``normalized_dense`` reward, success counted once per
episode, evaluation at seeds 4242424242 + i. MIKASA's wrapper table (``apply_mikasa_vla_wrappers``)
gives SeqOfColors no ``CurriculumPhaseNoopActionWrapper``: actions act in every phase.

**Episode:** 3 of the 9 colours (red, lime, blue, yellow, magenta, cyan, maroon, olive, teal), drawn
without replacement, are shown one at a time, each as one cube alone at the table centre for the
same 1-5 steps (so the cue lasts 3-15 steps; a colour never repeats, so every colour change is a
new item); all cubes are hidden for 1-5 steps; then the 9 cubes reappear, shuffled along an arc
round the table, with the centre button (a dark base and a red cap) in front of them; the robot
must touch the cued cubes, then press the button and lift. Episodes last 400 steps; MIKASA masks
success out of ``terminated``, so an episode never ends early.

**Randomisations** (MIKASA's): the sequence (ordered, 9 * 8 * 7 draws); the cue item length (1-5
steps, one for all items) and the delay (1-5 steps); which arc position each colour takes, with a
jitter of ~1 cm (and >= 6 cm between cubes); the arm's initial joints. The button stands at the
cubes' mean position, 4 cm toward the robot.

**Success:** MIKASA's (``evaluate``), at any step: every cued cube touched, no other cube touched,
the touches in the cue's order (MIKASA's docstring and instruction say "in any order", but its
``wrong_order_touched`` compares the k-th distinct cube touched with the k-th cue item, and
refuses the press otherwise), no cube pushed more than 6 cm, the button pressed after the last
touch (the TCP within 2.5 cm of the cap's top and 6.5 cm of its axis, then lifted 8.5 cm) and the
robot static. A touch: the TCP within 2 cm of the point 2.5 cm above the cube's centre, arm static
(every joint < 0.2 rad/s), in the manipulation phase.

**Facts:** one per cue item, worded with its order, ``the first cue cube was red.``, ``the second cue
cube was blue.``, ``the third cue cube was teal.``: each item is its own memory key (type, entity,
relation), so the bank keeps them side by side, and the order words carry the order success needs.
Decoys are worded alike about other things (``the key was red.``). ``Episode.true_facts`` lists the
three; a prompt needs all of them (one missing: the expert touches out of order or never presses).

The writer sees every control step: it reads the cue's colour from the base camera's pixels
(``read_cue_colour``) and, at each colour it has not seen this episode, writes the next item's fact.
The controller sees ``SeqControllerObservation`` only (never ``oracle_info``), so the sequence reaches
it only through its prompt.

**Progress as memory**: nothing in sight changes when a cube is touched, so a controller that reads only the current
frame and its prompt cannot tell which cubes it has touched. The writer then also writes what has been done, as
TASK_PROGRESS facts: ``the red cube was touched.`` and ``the button was pressed.``. It reads where each cube stands
from the base camera (``layout_perception.read_cube_layout``, each colour's first sighting in a frame that shows two
or more cubes, so never the cue's: within 0.55 cm of the simulator's), and the TCP and joint speeds from the arm's
own sensors: a touch is the arm static (every joint slower than 0.18 rad/s) with the TCP within 1.8 cm of the point
2.5 cm above a seen cube's centre (MIKASA: 2 cm, 0.2 rad/s); a press, the TCP within 3 cm of the button's axis and
2 cm over its cap (MIKASA: 6.5 and 2.5 cm), the button standing 4 cm from the seen cubes' mean toward the robot
(MIKASA's placement). Its expert is the stateless ``SequenceTouchController(progress_from="prompt")``, which learns
what it has done from those facts alone. ``SeqOfColorsTask(env_id, progress=False)`` is the task without progress
facts, whose expert keeps track of its own touches (state across calls).
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.memory.schema import Key, MemoryType
from sb3_memret.controllers.prompts import PromptTemplate, build_prompt
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.touch_expert import FACT_TEMPLATE
from sb3_memret.tasks.mikasa.core.layout_perception import LAYOUT_PLANE_Z, read_cube_layout
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES, ControllerObservation, stack_positions, read_cue_colour
from sb3_memret.tasks.mikasa.core.sequence_expert import (BUTTON_TOP_ABOVE_BASE, CUBE_TOUCH_OFFSET, ORDINALS, PRESSED_FACT,
                                                     TOUCHED_FACT, SequenceGains, SequenceTouchController)

# MIKASA's LANGUAGE_INSTRUCTION in the prompt contract's form (lowercase; it parses as is). Its "in any order"
# is MIKASA's wording; MIKASA's success checks the order (see the module docstring).
INSTRUCTION = ("observe which colored cubes appear during the cue, wait, then touch all of them in any order "
               "and press the center button.")
CUE_ENTITY = "cue cube"  # the k-th item's entity is "{ordinal} cue cube"
CUE_FACT = "the {ordinal} cue cube was {colour}."
PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(FACT_TEMPLATE,))
# with progress facts: theirs first, so "the red cube was touched." is not read as FACT_TEMPLATE's colour "touched"
PROGRESS_PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,),
                                          fact_templates=(TOUCHED_FACT, PRESSED_FACT, FACT_TEMPLATE))
TOUCHED, PRESSED = "touched", "pressed"  # the TASK_PROGRESS values, worded by PROGRESS_WORDINGS
PROGRESS_WORDINGS = {(MemoryType.TASK_PROGRESS, TOUCHED): "the {entity} was touched.",
                     (MemoryType.TASK_PROGRESS, PRESSED): "the {entity} was pressed."}
BUTTON_BASE_Z = 0.015  # MIKASA's button base centre height
BUTTON_TOWARD_ROBOT = 0.04  # MIKASA places the button at the cubes' mean position, this far toward the robot (-x)
SEQ_TASKS = {"SeqOfColors3-VLA-v0": 3}  # measured (lab/2026-11-23-the-memory-learner-on-the-scripted-experts/mikasa_probe.py) for these only
EPISODE_STEPS = 400
N_COLOURS = 9  # every SeqOfColors task has all nine cubes


def item_entity(k: int) -> str:
    """The entity of the cue's ``k``-th item (0-based): ``first cue cube``, ``second cue cube``, ..."""
    return f"{ORDINALS[k]} {CUE_ENTITY}"


def item_key(k: int) -> Key:
    return (MemoryType.OTHER, item_entity(k), "was")


def sequence_facts(colours: tuple[str, ...] | list[str]) -> list[str]:
    """One fact per cue item, in the cue's order."""
    return [CUE_FACT.format(ordinal=ORDINALS[k], colour=c) for k, c in enumerate(colours)]


def sequence_prompt(colours: tuple[str, ...] | list[str] | None) -> str:
    """The controller's prompt: the instruction, plus one fact per cue item when ``colours`` is given."""
    return build_prompt(INSTRUCTION, sequence_facts(colours or []), PROMPT_TEMPLATE)


def sequence_expert(chunk_len: int = 8, progress_from: str = "observation") -> SequenceTouchController:
    """The scripted expert: touches the prompt's colours in order, presses the button; holds still without one.
    ``progress_from="prompt"``: stateless, it learns what it has done from its prompt's progress facts."""
    template = PROGRESS_PROMPT_TEMPLATE if progress_from == "prompt" else PROMPT_TEMPLATE
    return SequenceTouchController(template, chunk_len, progress_from=progress_from)


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


class SequenceWriter:
    """Writes ``the {k-th} cue cube was {colour}.`` at the control step the base camera first showed the
    k-th colour alone at the centre. MIKASA draws the sequence without replacement, so a colour not yet
    seen this episode is the next item (a frame read as nothing in between changes nothing). One writer
    serves one env; the reset frame (``steps == 0``) starts its episode.

    With ``progress``, it also writes ``the {colour} cube was touched.`` and ``the button was pressed.`` at the end of
    the chunk whose last frame shows them (the module docstring says how): those frames must carry the camera's cube
    layout (``state["seen_cubes"]``) and the arm's sensors (``extra/tcp_pose``, ``agent/qvel``)."""

    def __init__(self, n_items: int = 3, progress: bool = False, gains: SequenceGains | None = None):
        self.n_items, self.progress, self.gains = n_items, progress, gains or SequenceGains()
        self.relations = {"cue": (MemoryType.OTHER, "was")}
        if progress:
            self.relations.update({TOUCHED: (MemoryType.TASK_PROGRESS, "was"),
                                   PRESSED: (MemoryType.TASK_PROGRESS, "was")})
        self.seen: list[str] = []
        self.layout: dict[str, np.ndarray] = {}
        self.touched: list[str] = []
        self.pressed = False

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self.seen, self.layout, self.touched, self.pressed = [], {}, [], False
        out = []
        for step, colour in frame.timed_percepts():
            if colour is None or colour in self.seen or len(self.seen) >= self.n_items:
                continue
            self.seen.append(colour)
            out.append((step, {("cue", item_entity(len(self.seen) - 1)): colour}))
        if self.progress:
            out += [(frame.steps, predicates) for predicates in self._progress(frame)]
        return out

    def _progress(self, frame: EnvFrame) -> list[Predicates]:
        """What the frame shows was done, not written before: a touch of a seen cube, the press."""
        if not isinstance(frame.state, Mapping) or "seen_cubes" not in frame.state:
            raise ValueError("a progress writer reads frames carrying the camera's cube layout (state['seen_cubes'], "
                             "from SeqOfColorsTask(progress=True).frames); this frame has none")
        seen = frame.state["seen_cubes"]
        if len(seen) >= 2:  # the cubes are out (the cue shows one at the table centre, not where it will stand)
            for colour, point in seen.items():
                self.layout.setdefault(colour, np.asarray(point, dtype=np.float64))
        g = self.gains
        tcp = as_numpy(frame.obs["extra"]["tcp_pose"]).reshape(-1)[:3].astype(np.float64)
        static = float(np.abs(as_numpy(frame.obs["agent"]["qvel"]).reshape(-1)[:7]).max()) <= g.static_tol
        if len(self.layout) < 2 or not static:  # the cue or the delay, or the arm moving: nothing done
            return []
        done: list[Predicates] = []
        for colour, (x, y) in self.layout.items():
            touch_point = np.array([x, y, LAYOUT_PLANE_Z + CUBE_TOUCH_OFFSET])
            if colour not in self.touched and np.linalg.norm(tcp - touch_point) < g.touch_tol:
                self.touched.append(colour)
                done.append({(TOUCHED, f"{colour} cube"): TOUCHED})
        if self.touched and not self.pressed and len(self.layout) == N_COLOURS:
            button = np.mean(list(self.layout.values()), axis=0) - (BUTTON_TOWARD_ROBOT, 0.0)
            top = BUTTON_BASE_Z + BUTTON_TOP_ABOVE_BASE
            if np.linalg.norm(tcp[:2] - button) < g.press_xy and tcp[2] <= top + g.press_seen:
                self.pressed = True
                done.append({(PRESSED, "button"): PRESSED})
        return done


class SeqOfColorsTask(MikasaCueTask):
    """MIKASA-Robo-VLA's SeqOfColors3-VLA-v0: touch the cubes of the colours shown one by one, earlier, in
    their order, then press the centre button."""

    field, detector_key, truth_attribute = "colour", "cube", "true_color_indices"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, "was", CUE_FACT
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, COLOUR_NAMES
    observation_wrapper: ClassVar = SeqControllerObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives SeqOfColors none: actions act in every phase
    max_control_steps = EPISODE_STEPS
    ends_at_success = True  # MIKASA masks success out of terminated; its success once is over by then
    success_reward = 1.0  # normalized_dense pays 400 / 400 at every step it reads success

    def __init__(self, env_id: str = "SeqOfColors3-VLA-v0", progress: bool = True):
        if env_id not in SEQ_TASKS:
            raise ValueError(f"unknown or unmeasured SeqOfColors task {env_id!r}; expected one of {sorted(SEQ_TASKS)}")
        super().__init__(env_id, N_COLOURS)
        self.n_items, self.progress = SEQ_TASKS[env_id], progress
        if progress:
            self.template, self.wordings = PROGRESS_PROMPT_TEMPLATE, PROGRESS_WORDINGS

    @property
    def colours(self) -> tuple[str, ...]:
        return self.words

    def read_cue(self, rgb: np.ndarray) -> str | None:
        return read_cue_colour(rgb, N_COLOURS)

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs = to_numpy(obs)
        base = env.unwrapped  # privileged: for metrics only
        success = as_numpy(info["success"]).reshape(-1)
        sequences = as_numpy(base.true_color_indices).reshape(len(success), -1)
        durations = as_numpy(base.cue_step_duration_per_env).reshape(-1)
        states = [{"colours": tuple(self.colours[int(c)] for c in sequences[i]), "cue_step_duration": int(durations[i])}
                  for i in range(len(success))]
        if self.progress:
            params = base.get_sensor_params()["base_camera"]
            intrinsic, extrinsic = as_numpy(params["intrinsic_cv"]), as_numpy(params["extrinsic_cv"])
            rgb = obs["sensor_data"]["base_camera"]["rgb"]
            touched = as_numpy(base.touched_cubes_idx).reshape(len(success), -1)
            # a press begun (MIKASA's pending one) or counted: the writer writes it at the press's bottom too
            pressed = as_numpy(base.pending_press).reshape(-1) | (as_numpy(base.button_press_count).reshape(-1) > 0)
            for i, state in enumerate(states):
                # what the base camera shows of the cubes, read with its calibration (the writer's)
                state["seen_cubes"] = read_cube_layout(rgb[i], intrinsic[i], extrinsic[i], N_COLOURS)
                # what MIKASA counted done (privileged: the fixed conditions' progress facts)
                state["touched"] = tuple(self.colours[int(c)] for c in touched[i] if c >= 0)
                state["pressed"] = bool(pressed[i])
        return [EnvFrame(select_obs(obs, i), states[i], None, bool(success[i])) for i in range(len(success))]

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> SequenceWriter:
        return SequenceWriter(self.n_items, self.progress)

    def episode(self, frame: EnvFrame) -> Episode:
        colours = tuple(frame.state["colours"])
        facts = tuple((item_key(k), c) for k, c in enumerate(colours))
        return Episode("cue cubes", colours[0], facts,
                       {"cue_colours": " ".join(colours), "cue_step_duration": frame.state["cue_step_duration"]})

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
        """The same ordinals, each naming a colour that was not cued (the first such colours, in palette order)."""
        cued = self.sequence(episode)
        others = [c for c in self.colours if c not in cued]
        return sequence_facts(others[: len(cued)])

    def expert(self) -> SequenceTouchController:
        return sequence_expert(progress_from="prompt" if self.progress else "observation")

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.with_state_extra(super().demo_features(with_images), "button")

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.append_state(super().demo_frame(obs, with_images), obs["extra"]["button_position"])


__all__ = ["CUE_FACT", "EPISODE_STEPS", "INSTRUCTION", "PROGRESS_PROMPT_TEMPLATE", "PROGRESS_WORDINGS",
           "PROMPT_TEMPLATE", "SEQ_TASKS", "SeqControllerObservation", "SeqOfColorsTask",
           "SequenceWriter", "item_entity", "item_key", "sequence_expert", "sequence_facts", "sequence_prompt"]
