"""A scripted frozen controller for MIKASA's BlinkCountButtonPress tasks: press the red button as many times as the
prompt says, then the black button.

It stands in for a VLA finetuned on these tasks with the blink count written into its prompt (``the blue lamp
blinked three times.``): the count comes only from the prompt's first fact that states one, whatever the fact is
about (a decoy, ``the key blinked twice.``, misleads it as a wrong fact would). With none it presses once, a guess
(success at chance: one episode in three on Easy, one in five on Medium).

It reads what ``BlinkCountObservation`` gives: its joints, its hand, where the two buttons stand (a detector) and
whether the phase lamp shows green (as the camera shows it), never the simulator's counters. Unlike a stateless
expert it keeps per-env state (``stateful = True``): nothing in sight tells how often the red button was pressed
(the cap springs back), so it counts the presses it has made itself. A press is recorded when an observation shows
the TCP as low over the red cap as MIKASA needs for one (MIKASA: within 2.51 cm of the cap's top and 6.5 cm of its
axis; recorded: 2 cm and 3 cm), and it counts once the TCP is seen lifted 12 cm over the cap's top (MIKASA: 8.5 cm
above where the press began, at most 11 cm over the top), so every press it counts is one MIKASA counted, and a
press MIKASA counted is never missed: each chunk heads for one point (the bottom of a press, or the top of its lift)
and holds there, so the next observation finds the TCP where the chunk ended. ``reset``/``reset_envs`` clear the
state of the envs they start.

Plan, each call (replanned from the observation and the current prompt): until the phase lamp is green (the cue:
MIKASA counts no press then) wait 13 cm over the red button's cap; then, fingers closed, come straight down to
8 mm over the cap's top (MIKASA pushes the cap down with the TCP, which never touches it) and back up 13 cm, as
many times as the count; then over to the black button, down 8 mm over its cap's top (MIKASA's submission), and
back up. Motion within a chunk uses ``ScriptedTouchController``'s fitted model of the ``pd_ee_delta_pose`` arm.

**Stateless, with progress as memory** (``progress_from="prompt"``): the presses made so far come from the prompt's
progress fact (``the red button was pressed twice.``, ``PRESSED_FACT``, which the task's progress writer writes
from the arm's own sensors), and nothing is kept between calls. Whether the hand is going down to a press or up
from one is read from where it is and which way it moves: low over the red cap, up; at the top of a lift, down (if
presses remain); in between, on the way it moves (its joints' speeds), and up when it stands still, since a lift
never adds a press. A controller that reads only the current frame and its prompt can imitate it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT, ScriptedTouchController, TouchGains, tcp_velocity
from sb3_memret.tasks.mikasa.core.sequence_expert import BUTTON_TOP_ABOVE_BASE, Goal

# a count as the facts word it: the prompt contract's fields hold words, and "blinked once." reads as English
# (up to MIKASA's most, 30 blinks in BlinkCountButtonPressHard-Long; "twenty one times": words, no hyphen)
_UNITS = ("one", "two", "three", "four", "five", "six", "seven", "eight", "nine")
_TEENS = ("ten", "eleven", "twelve", "thirteen", "fourteen", "fifteen", "sixteen", "seventeen", "eighteen", "nineteen")
COUNTS: tuple[str, ...] = ("once", "twice", *(f"{n} times" for n in (*_UNITS[2:], *_TEENS, "twenty",
                                                                     *(f"twenty {u}" for u in _UNITS), "thirty")))
RED, BLACK = 0, 1  # the button detector's entries: the red button (count), the black one (submit)
GRIP_CLOSED = -1.0
# the progress fact: how often the red button has been pressed (its field is not "count", which the cue's fact holds)
PRESSED_FACT = "the red button was pressed {presses}."
PROGRESS_SOURCES = ("observation", "prompt")  # where the expert learns the presses made so far


def count_value(n: int) -> str:
    """The fact's value for ``n`` blinks: ``once``, ``twice``, ``three times`` ..."""
    if not 1 <= n <= len(COUNTS):
        raise ValueError(f"a count must be 1-{len(COUNTS)}, got {n}")
    return COUNTS[n - 1]


def parse_count(value: str) -> int | None:
    """The count a fact's value states (``three times``: 3), or None for another value."""
    return COUNTS.index(value) + 1 if value in COUNTS else None


def stated_count(parsed: ParsedPrompt) -> int | None:
    """The count of the prompt's first fact that states one, or None."""
    for fact in parsed.facts:
        count = parse_count(dict(fact.fields).get("count", ""))
        if count is not None:
            return count
    return None


def stated_presses(parsed: ParsedPrompt) -> int:
    """The presses the prompt's progress fact says were made (``PRESSED_FACT``; the most, if several), else 0."""
    counts = [parse_count(dict(fact.fields).get("presses", "")) for fact in parsed.facts
              if fact.template == PRESSED_FACT]
    return max((n for n in counts if n is not None), default=0)


@dataclass(frozen=True)
class PressGains:
    """Where the TCP aims over a cap's top, and the margins on MIKASA's thresholds it counts its presses by."""

    press_height: float = 0.008  # the bottom of a press (MIKASA counts one below 0.0251)
    press_seen: float = 0.02  # record a press with the TCP this low over the cap's top ...
    press_xy: float = 0.03  # ... and this close to its axis (MIKASA: 0.065)
    lift_height: float = 0.13  # the top of a lift, where it also waits through the cue ...
    lift_seen: float = 0.12  # ... and the press counts once the TCP is above this (MIKASA: at most 0.1101)
    capture: float = 0.01  # the funnel's bottom: this close sideways, the TCP heads straight for the press point
    moving: float = 0.02  # stateless: a vertical TCP speed (m/s) above this says which way the hand is going


@dataclass
class PressProgress:
    """One env's episode so far, as the controller saw it."""

    presses: int = 0  # presses of the red button counted (pressed, then lifted)
    lifting: bool = False  # a press of the red button seen, its lift not yet
    submitted: bool = False  # the black button pressed


class ButtonPressController(ScriptedTouchController):
    """Presses the red button (``extra/button_positions`` entry 0) as many times as its prompt's count, each press
    lifted before the next, then the black button (entry 1), once the phase lamp is green (``extra/lamp_green``).
    ``default_count``: the presses without a count in the prompt (a guess). ``progress_from``: ``observation`` counts
    its own presses (per-env state: reset it with ``reset``/``reset_envs``); ``prompt`` reads them from the prompt's
    progress fact and keeps no state."""

    stateful = True

    def __init__(self, prompt_template: PromptTemplate, default_count: int = 1, chunk_len: int = 8,
                 gains: TouchGains | None = None, press_gains: PressGains | None = None,
                 progress_from: str = "observation"):
        super().__init__(chunk_len, gains or TouchGains(grip=GRIP_CLOSED), vocabulary=COUNTS, field="count",
                         prompt_template=prompt_template, key="button")
        count_value(default_count)  # a count a fact can state, or a ValueError
        if progress_from not in PROGRESS_SOURCES:
            raise ValueError(f"unknown progress_from {progress_from!r}; expected one of {list(PROGRESS_SOURCES)}")
        if progress_from == "prompt" and PRESSED_FACT not in prompt_template.fact_templates:
            raise ValueError(f"progress_from='prompt' needs the progress fact {PRESSED_FACT!r} in the prompt template; "
                             f"got {prompt_template.describe()}")
        self.default_count = default_count
        self.press = press_gains or PressGains()
        self.progress_from = progress_from
        self.stateful = progress_from == "observation"
        self.progress: list[PressProgress] = []

    def reset(self, seeds: Sequence[int]) -> None:
        super().reset(seeds)
        self.progress = [PressProgress() for _ in seeds]

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        super().reset_envs(env_ids, seeds)
        for i in env_ids:
            self.progress[i] = PressProgress()

    def count_of(self, parsed: ParsedPrompt) -> int:
        """The presses the prompt asks for, or the default guess without a count."""
        return stated_count(parsed) or self.default_count

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        extra = obs["extra"]
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        buttons = as_numpy(extra["button_positions"]).astype(np.float64)
        green = as_numpy(extra["lamp_green"]).astype(bool).reshape(-1)
        velocity = tcp_velocity(as_numpy(obs["agent"]["qpos"]), as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            if self.stateful:
                goal = self._goal(self.progress[i], self.count_of(p), tcp[i, :3], buttons[i], bool(green[i]))
            else:
                goal = self._stateless_goal(stated_presses(p), self.count_of(p), tcp[i, :3], float(velocity[i, 2]),
                                            buttons[i], bool(green[i]))
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, goal)
        return chunks

    def _caps(self, buttons: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The red and the black cap's tops."""
        return tuple(buttons[j] + (0.0, 0.0, BUTTON_TOP_ABOVE_BASE) for j in (RED, BLACK))

    def _low_over(self, pos: np.ndarray, top: np.ndarray) -> bool:
        s = self.press
        return bool(np.linalg.norm(pos[:2] - top[:2]) < s.press_xy and pos[2] <= top[2] + s.press_seen)

    def _goal(self, progress: PressProgress, count: int, pos: np.ndarray, buttons: np.ndarray, green: bool) -> Goal:
        """Record what this observation shows was done, then where to head."""
        s = self.press
        red, black = self._caps(buttons)
        if not green:  # the cue: presses do not count yet
            return Goal(red + (0.0, 0.0, s.lift_height), funnel=False)
        low_over = [self._low_over(pos, top) for top in (red, black)]
        if progress.lifting and pos[2] >= red[2] + s.lift_seen:
            progress.presses, progress.lifting = progress.presses + 1, False
        elif not progress.lifting and progress.presses < count and low_over[RED]:
            progress.lifting = True
        if progress.lifting:
            return Goal(red + (0.0, 0.0, s.lift_height), funnel=False)
        if progress.presses < count:
            return Goal(red + (0.0, 0.0, s.press_height))
        progress.submitted |= low_over[BLACK]
        if progress.submitted:
            return Goal(black + (0.0, 0.0, s.lift_height), funnel=False)
        return Goal(black + (0.0, 0.0, s.press_height))

    def _stateless_goal(self, presses: int, count: int, pos: np.ndarray, rising: float, buttons: np.ndarray,
                        green: bool) -> Goal:
        """Where to head from this observation alone: ``presses`` made (the prompt's), the TCP's vertical speed
        ``rising`` (m/s) telling a press's way down from its lift."""
        s = self.press
        red, black = self._caps(buttons)
        lift, press = Goal(red + (0.0, 0.0, s.lift_height), funnel=False), Goal(red + (0.0, 0.0, s.press_height))
        if not green:  # the cue: presses do not count yet
            return lift
        if presses < count:
            if self._low_over(pos, red):
                return lift
            near = np.linalg.norm(pos[:2] - red[:2]) < s.press_xy
            if not near or pos[2] >= red[2] + s.lift_seen or rising < -s.moving:
                return press  # from elsewhere, from the top of a lift, or on the way down: (on) to the press
            return lift  # on the way up, or standing in between: a lift never adds a press
        if self._low_over(pos, black):
            return Goal(black + (0.0, 0.0, s.lift_height), funnel=False)
        return Goal(black + (0.0, 0.0, s.press_height))

    def _waypoint(self, pos: np.ndarray, goal: Any) -> np.ndarray:
        """Where to head next: ``goal.point``, never below the funnel over it when ``goal.funnel`` (the TCP comes
        down onto a cap from above, straight down once it is within ``capture`` sideways), straight otherwise."""
        point = np.asarray(goal.point, dtype=np.float64)
        if not goal.funnel:
            return point
        g = self.gains
        sideways = max(0.0, float(np.linalg.norm(point[:2] - pos[:2])) - self.press.capture)
        return point + (0.0, 0.0, min(g.hover_height, g.funnel_slope * sideways))


__all__ = ["BLACK", "COUNTS", "ButtonPressController", "PRESSED_FACT", "PROGRESS_SOURCES", "PressGains",
           "PressProgress", "RED", "count_value", "parse_count", "stated_count", "stated_presses"]
