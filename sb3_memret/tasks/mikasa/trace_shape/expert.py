"""A scripted frozen controller for MIKASA's TraceShape: carry the green cube round the path its prompt names.

It stands in for a VLA finetuned on TraceShape with the demonstrated path written into its prompt (``the red cube
traced a square round -112 31 mm from -190 -40 mm.``: its shape, its centre and its start on the table). The path
comes only from the prompt's first fact that names one, whatever the fact is about (a decoy, ``the key traced a
circle round ...``, misleads it as a wrong fact would); without one it grasps the cube and holds it, a guess that
never succeeds. It keeps no state: every ``act`` re-reads the observation and the prompt. It reads only what
``TraceShapeObservation`` gives (joints, hand pose, the green cube's position, as a detector reports it).

Plan, each call: while the cube is not in its fingers, come down a funnel over it with the gripper open (rising
straight up first where the hand is below the funnel, so that low fingers do not sweep the cube away) and close it
only once the hand is measured at the cube's centre (``TraceGains.seize_above``): fingers closed higher pinch the
cube's top edges, and the cube swings round them and falls while traced. Holding it, lift it to ``carry_z`` and
steer it round the path: at every predicted step of the chunk, towards the waypoint ``lookahead`` places past the one
nearest the cube (a pure pursuit, always forward, so it joins the path wherever it is nearest and goes round and
round). MIKASA counts a checkpoint once the cube's xy passes within 3.5 cm of it after the lamp turns green, and
succeeds when all twelve are visited and the cube is back by the first: within one lap of the green lamp. Motion
within a chunk uses ``ScriptedTouchController``'s fitted model of the ``pd_ee_delta_pose`` arm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.carry_expert import GRIP_CLOSED, GRIP_OPEN, CarryGains
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT, ScriptedTouchController, TouchGains, tcp_velocity
from sb3_memret.tasks.mikasa.trace_shape.paths import SHAPES, TracedPath


@dataclass(frozen=True)
class TraceGains:
    """The carry and the pursuit (metres, waypoints)."""

    carry_z: float = 0.045  # the held cube's centre while tracing (its bottom 2.5 cm over the table)
    lookahead: int = 2  # steer towards the waypoint this many past the nearest (1-2 cm apart)
    max_step: float = 0.025  # the cube's largest step a control step while tracing (corners stay within reach)
    held_reach: float = 0.035  # the fingers on a cube this close to the TCP: held (a cube swung in the fingers too)
    held_gap: tuple[float, float] = (0.02, 0.06)  # ... with this gap between them (a cube tilted in the fingers too)
    grasp_below: float = 0.004  # aim the grasp this far below the cube's centre (the arm stops within 8 mm of it) ...
    seize_above: float = 0.006  # ... and close the fingers once the TCP is measured no higher over the centre ...
    seize_sideways: float = 0.01  # ... and this close to it sideways (fingertips 9 mm below the TCP: pads centred)
    funnel_slack: float = 0.015  # the hand this far below the funnel over the cube: rise straight up first


class TraceGoal(NamedTuple):
    """Where a chunk heads and how: ``grasp`` (open, down a funnel onto ``point``), ``seize`` (closing there),
    ``hold`` (at ``point``, closed), ``trace`` (round ``path``, the cube ``hand`` off the TCP); the sequence's
    ``release``, ``rise`` (open, to ``point``) and ``press`` (closed, down a funnel onto ``point``)."""

    point: np.ndarray
    mode: str
    path: np.ndarray | None = None
    hand: np.ndarray | None = None


def path_of(parsed: ParsedPrompt) -> TracedPath | None:
    """The path the prompt's first fact that names one describes, or None."""
    for fact in parsed.facts:
        shape = fact.value("shape")
        if shape in SHAPES:
            centre = (int(fact.value("cx")), int(fact.value("cy")))
            return TracedPath(shape, centre, (int(fact.value("sx")), int(fact.value("sy"))))
    return None


class TraceShapeController(ScriptedTouchController):
    """Carries the green cube round the path its prompt's fact names (fields ``shape``, ``cx``, ``cy``, ``sx``,
    ``sy``: millimetres)."""

    stateful = False

    def __init__(self, prompt_template: PromptTemplate, chunk_len: int = 8, gains: TouchGains | None = None,
                 carry: CarryGains | None = None, trace: TraceGains | None = None):
        super().__init__(chunk_len, gains, vocabulary=SHAPES, field="shape", prompt_template=prompt_template,
                         key="cube")
        self.carry = carry or CarryGains()
        self.trace = trace or TraceGains()

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        tcp = as_numpy(obs["extra"]["tcp_pose"]).astype(np.float64)
        cube = as_numpy(obs["extra"]["cube_positions"]).astype(np.float64)[:, 0]
        qpos = as_numpy(obs["agent"]["qpos"]).astype(np.float64)
        velocity = tcp_velocity(qpos, as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            goal = self._goal(tcp[i, :3], cube[i], qpos[i, 7:9].sum(), path_of(p))
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, goal)
        return chunks

    def _goal(self, pos: np.ndarray, cube: np.ndarray, gap: float, path: TracedPath | None) -> TraceGoal:
        t = self.trace
        held = t.held_gap[0] <= gap <= t.held_gap[1] and np.linalg.norm(pos - cube) <= t.held_reach
        if not held:
            return self._grasp(pos, cube)
        hand = pos - cube  # the cube sits off the TCP in the fingers: steer the cube, not the TCP
        if path is None:
            return TraceGoal(np.array([cube[0], cube[1], t.carry_z]) + hand, "hold")
        return TraceGoal(pos.copy(), "trace", path.waypoints(), hand)

    def _grasp(self, pos: np.ndarray, cube: np.ndarray) -> TraceGoal:
        """Down the funnel onto the grasp point, just below the cube's centre; ``seize`` once the TCP is measured
        there (a prediction that runs ahead of a lagging arm closed the fingers on the cube's top edges)."""
        t = self.trace
        point = cube - (0.0, 0.0, t.grasp_below)
        there = np.linalg.norm(pos[:2] - cube[:2]) <= t.seize_sideways and pos[2] - cube[2] <= t.seize_above
        return TraceGoal(point, "seize" if there else "grasp")

    def _funnel(self, pos: np.ndarray, point: np.ndarray) -> np.ndarray:
        """Towards the funnel's point over ``point`` at the hand's sideways distance; straight up first where the hand
        is more than ``funnel_slack`` below that (low fingers moving sideways push the cube away)."""
        g = self.gains
        height = point[2] + min(g.hover_height, g.funnel_slope * float(np.linalg.norm(point[:2] - pos[:2])))
        if pos[2] < height - self.trace.funnel_slack:
            return np.array([pos[0], pos[1], height])
        return np.array([point[0], point[1], height])

    def _waypoint(self, pos: np.ndarray, goal: Any) -> np.ndarray:
        """Grasping: the grasp point, never below a funnel over it. Holding: the point. Tracing: rise to the carry
        height first, then the pursuit point past the waypoint nearest the (predicted) cube."""
        if goal.mode in ("grasp", "seize"):
            return self._funnel(pos, np.asarray(goal.point, dtype=np.float64))
        if goal.mode == "hold":
            return np.asarray(goal.point, dtype=np.float64)
        t = self.trace
        cube = pos - goal.hand
        if cube[2] < t.carry_z - self.carry.lift_first:
            return np.array([pos[0], pos[1], t.carry_z + goal.hand[2]])
        nearest = int(np.argmin(np.linalg.norm(goal.path - cube[:2], axis=1)))
        target = goal.path[(nearest + t.lookahead) % len(goal.path)]
        step = np.array([target[0] - cube[0], target[1] - cube[1]])
        step *= min(1.0, t.max_step / max(float(np.linalg.norm(step)), 1e-9))
        return np.array([cube[0] + step[0], cube[1] + step[1], t.carry_z]) + goal.hand

    def _grip(self, pos: np.ndarray, goal: Any) -> float:
        return GRIP_CLOSED if goal.mode in ("seize", "hold", "trace") else GRIP_OPEN


__all__ = ["TraceGains", "TraceGoal", "TraceShapeController", "path_of"]
