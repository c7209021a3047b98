"""A scripted frozen controller for MIKASA's TraceShapeSeq: carry the green cube round each path of its prompt's
sequence in order, then press the button.

It stands in for a VLA finetuned on TraceShapeSeq with the demonstrated sequence and its own progress written into its
prompt (``the red cube traced round -65 73 mm, a circle from 3 -17 mm, then a square from -149 41 mm.``, ``the green
cube traced one path.``). It keeps no state: which path comes next is the one after those its progress fact counts,
traced as ``TraceShapeController`` traces one; with every path traced it lets the cube go where it is, rises clear
of it and presses the button from above, on the button's side nearer the arm (MIKASA counts a press with the TCP
within 6.5 cm of the cap's axis and 2.5 cm over its top; a button far out is pressed from as near as the arm
reaches). It reads only what ``TraceSequenceObservation`` gives (joints, hand pose, the green cube's and the
button's positions, as a detector reports them).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.carry_expert import GRIP_CLOSED, GRIP_OPEN, CarryGains
from sb3_memret.tasks.mikasa.core.touch_expert import (COAST_GAIN, CONTROL_DT, DRIVE_GAIN, POS_SCALE, TouchGains,
                                                        tcp_velocity)
from sb3_memret.tasks.mikasa.trace_shape.expert import TraceGains, TraceGoal, TraceShapeController
from sb3_memret.tasks.mikasa.trace_shape.paths import TracedPath

ORDINAL_COUNTS: tuple[str, ...] = ("one path", "two paths", "three paths", "four paths", "five paths")
BUTTON_TOP_ABOVE_CAP = 0.014  # MIKASA's TraceShapeSeq button: the cap's top over its centre (the detector's point)


def sequence_of(parsed: ParsedPrompt) -> list[TracedPath] | None:
    """The paths, in order, that the prompt's first sequence fact names (fields ``cx``, ``cy``, ``shape1``, ``sx1``,
    ``sy1``, ...: one centre, each path's shape and start), or None."""
    for fact in parsed.facts:
        if fact.value("shape1") is None:
            continue
        centre = (int(fact.value("cx")), int(fact.value("cy")))
        paths, i = [], 1
        while (shape := fact.value(f"shape{i}")) is not None:
            paths.append(TracedPath(shape, centre, (int(fact.value(f"sx{i}")), int(fact.value(f"sy{i}")))))
            i += 1
        return paths
    return None


def paths_done(parsed: ParsedPrompt) -> int:
    """How many paths the prompt's progress fact says the green cube has traced (field ``paths``); 0 without one."""
    word = parsed.field("paths")
    return ORDINAL_COUNTS.index(word) + 1 if word in ORDINAL_COUNTS else 0


ARM_BASE_XY = (-0.615, 0.0)  # where MIKASA mounts the arm (every task: ``set_root_pose``)


@dataclass(frozen=True)
class PressGains:
    """The submission: where over the button the TCP presses (metres)."""

    press_height: float = 0.012  # the TCP over the cap's top (MIKASA counts a press once it is within 2.5 cm)
    near_side: float = 0.03  # press this far nearer the arm than the cap's centre (MIKASA: within 6.5 cm) ...
    reach: float = 0.805  # ... and no farther from the arm's base than this: the TCP pointing down reached 0.805 m
    release_rise: float = 0.06  # having let the cube go, rise this high over it before heading for the button
    command_reach: float = 0.81  # no step commands the TCP farther from the arm's base (an unsolvable target freezes
    # the arm where it is: ManiSkill's pd_ee_delta_pose keeps the joints when its IK fails; 500 steps lost that way)


def within_reach(chunk: np.ndarray, pos: np.ndarray, step: np.ndarray, reach: float) -> np.ndarray:
    """``chunk`` with each step's commanded translation cut back so that the point it commands (the predicted TCP plus
    the delta, ``pd_ee_delta_pose``) lies within ``reach`` of the arm's base sideways: beyond, its IK fails and the arm
    stands still. The TCP is predicted with ``ScriptedTouchController``'s fitted model."""
    chunk, pos, step = chunk.copy(), np.asarray(pos, dtype=np.float64).copy(), np.asarray(step, dtype=np.float64)
    base = np.asarray(ARM_BASE_XY)
    for k in range(len(chunk)):
        target = pos[:2] + POS_SCALE * chunk[k, :2]
        out = float(np.linalg.norm(target - base))
        if out > reach:
            chunk[k, :2] = (base + (target - base) * reach / out - pos[:2]) / POS_SCALE
        step = DRIVE_GAIN * POS_SCALE * chunk[k, :3] + COAST_GAIN * step
        pos = pos + step
    return chunk


def past_the_aim(aim: np.ndarray, by: float) -> np.ndarray:
    """The point ``by`` past ``aim`` (xy) away from the arm's base: heading there, the arm, which stops once within its
    arrival tolerance ``by`` of where it heads, stops at the aim and not short of it (a far button's press zone begins
    a few millimetres before the arm's reach: 7 mm short, it was never pressed)."""
    away = np.asarray(aim, dtype=np.float64) - np.asarray(ARM_BASE_XY)
    return aim + away / max(float(np.linalg.norm(away)), 1e-9) * by


class TraceSequenceController(TraceShapeController):
    """MIKASA's TraceShapeSeq: carries the green cube round each path of its prompt's sequence fact in order, the
    next one after those its progress fact says are traced (``paths_done``); with all traced, lets the cube go and
    presses the button (``extra/button_position``, the cap's centre, from the detector). Without a sequence it holds
    the cube, a guess that never succeeds."""

    def __init__(self, prompt_template: PromptTemplate, chunk_len: int = 8, gains: TouchGains | None = None,
                 carry: CarryGains | None = None, trace: TraceGains | None = None, press: PressGains | None = None):
        super().__init__(prompt_template, chunk_len, gains, carry, trace)
        self.press = press or PressGains()

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        tcp = as_numpy(obs["extra"]["tcp_pose"]).astype(np.float64)
        cube = as_numpy(obs["extra"]["cube_positions"]).astype(np.float64)[:, 0]
        button = as_numpy(obs["extra"]["button_position"]).astype(np.float64)
        qpos = as_numpy(obs["agent"]["qpos"]).astype(np.float64)
        velocity = tcp_velocity(qpos, as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            paths, done = sequence_of(p), paths_done(p)
            if paths is not None and done >= len(paths):
                goal = self._submit(tcp[i, :3], cube[i], qpos[i, 7:9].sum(), button[i])
            else:
                goal = self._goal(tcp[i, :3], cube[i], qpos[i, 7:9].sum(), None if paths is None else paths[done])
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, goal)
        return chunks

    def _submit(self, pos: np.ndarray, cube: np.ndarray, gap: float, button: np.ndarray) -> TraceGoal:
        """Every path traced: let the cube go where it is, rise clear of it, then press the button from above, on its
    side nearer the arm (within the arm's reach where the button stands far out)."""
        t, p = self.trace, self.press
        if t.held_gap[0] <= gap <= t.held_gap[1] and np.linalg.norm(pos - cube) <= t.held_reach:
            return TraceGoal(pos.copy(), "release")
        if np.linalg.norm(pos[:2] - cube[:2]) < p.release_rise and pos[2] < cube[2] + p.release_rise:
            return TraceGoal(np.array([pos[0], pos[1], cube[2] + p.release_rise + 0.02]), "rise")
        top = button[2] + BUTTON_TOP_ABOVE_CAP
        base = np.asarray(ARM_BASE_XY)
        away = button[:2] - base
        distance = float(np.linalg.norm(away))
        aim = base + away / max(distance, 1e-9) * min(distance - p.near_side, p.reach)
        return TraceGoal(np.array([aim[0], aim[1], top + p.press_height]), "press")

    def _chunk(self, tcp_pose: np.ndarray, step: np.ndarray, goal: Any) -> np.ndarray:
        """As tracing; pressing, every commanded point within the arm's reach (``within_reach``)."""
        chunk = super()._chunk(tcp_pose, step, goal)
        return within_reach(chunk, tcp_pose[:3], step, self.press.command_reach) if goal.mode == "press" else chunk

    def _waypoint(self, pos: np.ndarray, goal: Any) -> np.ndarray:
        """Releasing, rising: the point. Pressing: the point, never below a funnel over it. Else as tracing."""
        if goal.mode in ("release", "rise"):
            return np.asarray(goal.point, dtype=np.float64)
        if goal.mode == "press":
            g, point = self.gains, np.asarray(goal.point, dtype=np.float64)
            sideways = float(np.linalg.norm(point[:2] - pos[:2]))
            return np.array([*past_the_aim(point[:2], g.arrive_tol),
                             point[2] + min(g.hover_height, g.funnel_slope * sideways)])
        return super()._waypoint(pos, goal)

    def _grip(self, pos: np.ndarray, goal: Any) -> float:
        if goal.mode in ("release", "rise"):
            return GRIP_OPEN
        if goal.mode == "press":
            return GRIP_CLOSED
        return super()._grip(pos, goal)


__all__ = ["ARM_BASE_XY", "BUTTON_TOP_ABOVE_CAP", "ORDINAL_COUNTS", "PressGains", "TraceSequenceController",
           "past_the_aim", "paths_done", "sequence_of", "within_reach"]
