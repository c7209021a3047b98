"""A scripted frozen controller for MIKASA's colour-cue tasks (SeqOfColors, ChainOfColors, BunchOfColors): touch
the prompt's cue colours in their order, then press the centre button.

It stands in for a VLA finetuned on SeqOfColors with the cue sequence written into its prompt, one
fact per cue item (``the first cue cube was red. the second cue cube was blue. ...``). The colours
come only from the prompt: facts whose entity starts with an ordinal (``first``, ``second``, ...)
are put in that order; any other fact worded alike (a decoy, ``the key was lime.``) still adds its
colour, after the ordered ones, in prompt order (like RememberColor's expert it follows the colour
words whatever the fact is about, so a decoy misleads it). With no colour it knows, it holds still.

It reads only what ``SeqControllerObservation`` gives (joints, hand pose, the colour detector's cube
positions, the button detector's position), never the simulator. Unlike RememberColor's expert it
keeps per-env state (``stateful = True``): nothing in sight changes when a cube is touched, so it
remembers which colours it has touched and whether it has pressed the button. A touch is recorded
when an observation shows what MIKASA scores as one (the TCP within 2 cm of the point 2.5 cm above
a cube's centre and every arm joint slower than 0.2 rad/s), with margins, so it never records a
touch MIKASA did not count. ``reset``/``reset_envs`` clear the state of the envs they start.

Plan, each call (replanned from the observation and the current prompt): while any cube is out of
sight (cue and delay phases: a sequence shows one cube, a bunch a few) wait at a ready pose; else
touch the first prompt colour not yet touched (down a funnel over the cube, hold 3 cm above its
centre until the touch is seen); once all are touched, descend over the button (MIKASA counts a press when the TCP comes within 2.5 cm of the
cap's top), then lift 13 cm (MIKASA needs 8.5 cm above where the press began) and hold still
(MIKASA's success needs the robot static). Motion within a chunk uses ``ScriptedTouchController``'s
fitted model of the ``pd_ee_delta_pose`` arm.

With ``progress_from="prompt"`` it keeps no state (``stateful = False``): what has been done comes from its prompt's
progress facts (``the red cube was touched.``, ``the button was pressed.``, written by the task's writer from
what the camera and the arm's own sensors showed), the way a reactive policy that reads only the current frame and
its prompt would have to learn it. It then holds at a cube until its prompt says the cube was touched, and over the
button until it says the button was pressed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT, FACT_TEMPLATE, ScriptedTouchController, TouchGains, tcp_velocity
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES

PROGRESS_SOURCES = ("observation", "prompt")  # where the controller learns what it has done
TOUCHED_FACT = "the {touched} cube was touched."  # progress facts, in the prompt contract before FACT_TEMPLATE
PRESSED_FACT = "the button was pressed."
ORDINALS: tuple[str, ...] = ("first", "second", "third", "fourth", "fifth", "sixth", "seventh", "eighth", "ninth")

# MIKASA's SeqOfColorsVLABaseEnv geometry and thresholds (what "touched", "pressed" and "static" mean there)
CUBE_TOUCH_OFFSET = 0.025  # the touch point: CUBE_HALFSIZE + 0.005 above the cube's centre
CUBE_TOUCH_RADIUS = 0.02  # the TCP within CUBE_HALFSIZE of it ...
STATIC_QVEL = 0.2  # ... while every arm joint is slower than this (agent.is_static(0.2))
BUTTON_TOP_ABOVE_BASE = 0.043  # the cap's top over the button base's centre: 0.015 + 2 * 0.014
BUTTON_PRESS_Z = 0.0251  # a press: the TCP below the cap's top + 0.03 - 0.35 * 0.014 ...
BUTTON_PRESS_XY = 0.065  # ... within this of the button's axis
BUTTON_LIFT = 0.085  # then back up 0.1 - 0.015 above where the press began


@dataclass(frozen=True)
class SequenceGains:
    """Where the TCP aims and the margins on MIKASA's thresholds it checks progress by."""

    touch_height: float = 0.03  # TCP over the cube centre at a touch: fingertips (9 mm lower) just clear its top
    touch_tol: float = 0.018  # record a touch within this of MIKASA's touch point (MIKASA: 0.02)
    static_tol: float = 0.18  # ... with every arm joint slower than this (MIKASA: 0.2 rad/s)
    # the writer's stillness: the harness gives a policy no joint velocities, so the TCP moved less than this per
    # control step since the writer's last frame
    still_step: float = 0.001
    capture: float = 0.01  # the funnel's bottom: this close sideways, the TCP heads straight for the goal
    press_height: float = 0.012  # TCP over the cap's top when pressing (a full press; the fingers stay clear)
    press_seen: float = 0.02  # record the press with the TCP this low over the cap's top (MIKASA: 0.0251) ...
    press_xy: float = 0.03  # ... and this close to its axis (MIKASA: 0.065)
    lift_height: float = 0.13  # lift the TCP to this over the cap's top (MIKASA: press height + 0.085) ...
    lift_seen: float = 0.12  # ... and hold still once above this
    # leaving a touched cube: the fingertips rest on its top, and a TCP that heads sideways from there drags it
    # (MIKASA fails a cube pushed 6 cm; measured: 7.4 cm on SeqOfColors5, development seed 5001, on the way from
    # the last cube to the button); more than ``depart_sideways`` from the goal and lower than ``depart_height``,
    # the TCP rises straight up first
    depart_height: float = 0.08
    depart_sideways: float = 0.03


class Goal(NamedTuple):
    """Where a chunk heads: ``point``, reached down a funnel over it (``funnel``) or straight."""

    point: np.ndarray
    funnel: bool = True


@dataclass
class Progress:
    """One env's episode so far, as the controller saw it."""

    touched: list[str] = field(default_factory=list)  # colours, in the order the touches were seen
    pressed: bool = False
    lifted: bool = False


def ordered_colours(parsed: ParsedPrompt, vocabulary: Sequence[str] = COLOUR_NAMES,
                    field_name: str = "colour") -> list[str]:
    """The colours the prompt's facts name, in the order to touch them: facts whose entity begins with an
    ordinal word by that ordinal, then the others in prompt order; repeats and unknown words dropped."""
    ranked = []
    for position, fact in enumerate(parsed.facts):
        fields = dict(fact.fields)
        word = fields.get(field_name)
        if word not in vocabulary:
            continue
        first = str(fields.get("entity", "")).split(" ")[0]
        rank = ORDINALS.index(first) if first in ORDINALS else len(ORDINALS)
        ranked.append((rank, position, word))
    out: list[str] = []
    for _, _, word in sorted(ranked):
        if word not in out:
            out.append(word)
    return out


class SequenceTouchController(ScriptedTouchController):
    """Touches the cubes of the prompt's colours in their ordinal order, then presses and releases the
    button, then holds still. Keeps per-env progress: reset it with ``reset``/``reset_envs``."""

    stateful = True

    def __init__(self, prompt_template: PromptTemplate, chunk_len: int = 8, gains: TouchGains | None = None,
                 sequence_gains: SequenceGains | None = None, vocabulary: Sequence[str] = COLOUR_NAMES,
                 progress_from: str = "observation"):
        super().__init__(chunk_len, gains, vocabulary=vocabulary, field="colour", prompt_template=prompt_template,
                         key="cube")
        if progress_from not in PROGRESS_SOURCES:
            raise ValueError(f"unknown progress_from {progress_from!r}; expected one of {list(PROGRESS_SOURCES)}")
        if progress_from == "prompt" and not {TOUCHED_FACT, PRESSED_FACT} <= set(prompt_template.fact_templates):
            raise ValueError(f"progress_from='prompt' needs the progress facts {[TOUCHED_FACT, PRESSED_FACT]} in the "
                             f"prompt template; got {prompt_template.describe()}")
        self.progress_from = progress_from
        self.stateful = progress_from == "observation"
        self.seq = sequence_gains or SequenceGains()
        self.progress: list[Progress] = []

    def reset(self, seeds: Sequence[int]) -> None:
        super().reset(seeds)
        self.progress = [Progress() for _ in seeds]

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        super().reset_envs(env_ids, seeds)
        for i in env_ids:
            self.progress[i] = Progress()

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        plans = [ordered_colours(p, self.vocabulary, self.field) for p in parsed]
        if not any(plans):
            return chunks
        tcp = as_numpy(obs["extra"]["tcp_pose"]).astype(np.float64)
        cubes, visible, button = self._detections(obs)
        steps, static = self._motion(obs, tcp)
        for i, plan in enumerate(plans):
            if not plan:
                continue  # no colour it knows: hold still
            progress = self.progress[i] if self.progress_from == "observation" else \
                prompt_progress(parsed[i], self.vocabulary)
            goal = self._goal(progress, plan, tcp[i, :3], cubes[i], visible[i], button[i], bool(static[i]))
            if goal is not None:
                chunks[i] = self._chunk(tcp[i], steps[i], goal)
        return chunks

    def _detections(self, obs: Obs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each cube's position (B, n, 3) and whether it is in sight (B, n), and the button's base centre (B, 3):
        the detector's (``SeqControllerObservation``)."""
        extra = obs["extra"]
        return (as_numpy(extra["cube_positions"]).astype(np.float64), as_numpy(extra["cube_visible"]).astype(bool),
                as_numpy(extra["button_position"]).astype(np.float64))

    def _motion(self, obs: Obs, tcp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The TCP's motion over one control step at the observation (B, 3), and whether the arm is static (B,):
        from the joints' velocities through the arm's Jacobian; static as MIKASA means it, every joint slower than
        ``static_tol``."""
        qvel = as_numpy(obs["agent"]["qvel"]).astype(np.float64)
        static = np.abs(qvel[:, :7]).max(axis=1) <= self.seq.static_tol
        return tcp_velocity(as_numpy(obs["agent"]["qpos"]), qvel) * CONTROL_DT, static

    def _goal(self, progress: Progress, plan: list[str], pos: np.ndarray, cubes: np.ndarray, visible: np.ndarray,
              button: np.ndarray, static: bool) -> Goal | None:
        """Record what this observation shows was done (with progress from observation), then where to head (None:
        hold still)."""
        s, observed = self.seq, self.progress_from == "observation"
        if not visible.all():  # the cue (one cube, or a bunch on an arc) or the delay: the cubes are not out yet
            return Goal(np.asarray(self.gains.ready, dtype=np.float64), funnel=False)
        for index in np.flatnonzero(visible) if observed else ():
            name = self.vocabulary[index]
            touch_point = cubes[index] + (0.0, 0.0, CUBE_TOUCH_OFFSET)
            if static and name not in progress.touched and np.linalg.norm(pos - touch_point) < s.touch_tol:
                progress.touched.append(name)
        remaining = [c for c in plan if c not in progress.touched]
        if remaining:
            index = self.vocabulary.index(remaining[0])
            if not visible[index]:
                return Goal(np.asarray(self.gains.ready, dtype=np.float64), funnel=False)
            return Goal(cubes[index] + (0.0, 0.0, s.touch_height))
        top = button[2] + BUTTON_TOP_ABOVE_BASE
        if not progress.pressed:
            near = np.linalg.norm(pos[:2] - button[:2]) < s.press_xy
            if observed and near and pos[2] <= top + s.press_seen:
                progress.pressed = True
            else:
                return Goal(np.array([button[0], button[1], top + s.press_height]))
        if not progress.lifted:
            if pos[2] >= top + s.lift_seen:
                progress.lifted = True
            else:
                return Goal(np.array([button[0], button[1], top + s.lift_height]), funnel=False)
        return None

    def _waypoint(self, pos: np.ndarray, goal: Any) -> np.ndarray:
        """Where to head next: ``goal.point``, never below the funnel over it when ``goal.funnel`` (so the TCP
        rises before it crosses the table and comes down from above; its bottom is ``capture`` wide, so a TCP
        that stopped a few mm off sideways is not held up by it), and straight up first when it is low and still far
        sideways (leaving a cube it touched); straight otherwise."""
        if not isinstance(goal, Goal):
            return super()._waypoint(pos, goal)
        point = np.asarray(goal.point, dtype=np.float64)
        if not goal.funnel:
            return point
        g, s = self.gains, self.seq
        distance = float(np.linalg.norm(point[:2] - pos[:2]))
        if distance > s.depart_sideways and pos[2] < s.depart_height:
            return np.array([pos[0], pos[1], s.depart_height + 0.01])
        sideways = max(0.0, distance - s.capture)
        lift = min(g.hover_height, g.funnel_slope * sideways)
        return np.array([point[0], point[1], point[2] + lift])


def prompt_progress(parsed: ParsedPrompt, vocabulary: Sequence[str] = COLOUR_NAMES) -> Progress:
    """What the prompt's progress facts say was done: the touched colours in prompt order, and the press (the lift,
    not a fact, is read from where the TCP is)."""
    touched = [word for fact in parsed.facts if fact.template == TOUCHED_FACT
               for key, word in fact.fields if key == "touched" and word in vocabulary]
    return Progress(list(dict.fromkeys(touched)), any(fact.template == PRESSED_FACT for fact in parsed.facts))


__all__ = ["FACT_TEMPLATE", "Goal", "ORDINALS", "PRESSED_FACT", "PROGRESS_SOURCES", "Progress", "SequenceGains",
           "SequenceTouchController", "TOUCHED_FACT", "ordered_colours", "prompt_progress"]
