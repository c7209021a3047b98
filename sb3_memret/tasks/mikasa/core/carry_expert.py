"""A scripted frozen controller for MIKASA's TakeItBack: carry the cube onto the red target, then back to
where the prompt says it started.

It stands in for a VLA finetuned on TakeItBack with the start written into its prompt (``the cube
started at the left.``). It reads only what ``TakeItBackObservation`` gives (joints, hand pose, the
cube's position, which target is in sight and where), never the simulator, and keeps no state: every
``act`` re-reads the observation and the prompt. The start comes only from the prompt's first fact
that names a side, whatever the fact is about (a decoy, ``the key started at the right.``, misleads
it as a wrong fact would); with none it takes the cube back to the middle start, where a policy that
averages the starts would put it (MIKASA's 8 cm radius also counts that for the nearer left and right starts:
without memory it succeeds about half the time).

Plan, each call: while the cube is not in its fingers, come down a funnel over it with the gripper
open and close it at the cube's centre; holding it (fingers closed on a 4 cm gap, the TCP at the
cube), lift it to ``carry_height`` and carry it to the red target while that is in sight; once the
target has changed colour (MIKASA swaps the red target for a purple one when the cube reaches it),
carry it back to the start's centre and hold it there: along the target's side of the table (x of at least
``return_lane``, beyond 8 cm of every start) until level with the start, then straight in. MIKASA counts success at
any step, and a straight diagonal sweeps the cube within 8 cm of starts that are not the one it heads for: a wrong
fact succeeded by the way at 7 of 20 middle starts (protocol seeds). MIKASA's success needs only the cube's xy within
8 cm of its start after the target was reached, so the cube need not be set down. Motion within a
chunk uses ``ScriptedTouchController``'s fitted model of the ``pd_ee_delta_pose`` arm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT, ScriptedTouchController, TouchGains, named_word, tcp_velocity

GRIP_OPEN, GRIP_CLOSED = 1.0, -1.0
REACH_X = 0.19  # the farthest TCP x the arm reached pointing down, in 1 cm steps, at heights of 4 to 16 cm


@dataclass(frozen=True)
class CarryGains:
    """The grasp and the carry (metres)."""

    grasp_tol: float = 0.012  # close the gripper once the TCP is predicted this close to the cube's centre
    held_gap: tuple[float, float] = (0.03, 0.047)  # the fingers' gap when closed on the 4 cm cube ...
    held_reach: float = 0.02  # ... with the TCP this close to the cube's centre: the cube is in hand
    carry_height: float = 0.06  # the cube's centre while carried
    lift_first: float = 0.02  # below carry_height by more than this, rise before moving sideways
    placed: float = 0.01  # the cube's xy this close to the start's centre: hold still
    reach_x: float = 0.175  # carry no farther than this (x): the arm pointing down reaches about 0.19 m (measured)
    return_lane: float = 0.14  # carried back, keep the cube's x at least this (starts: x <= 0.05, 8 cm counts) ...
    level: float = 0.015  # ... until its y is this close to the start's, then come straight in


class CarryGoal(NamedTuple):
    """Where a chunk heads and how: ``grasp`` (down a funnel onto ``point``, closing there) or ``carry``."""

    point: np.ndarray
    mode: str


class CarryBackController(ScriptedTouchController):
    """Carries the cube to the red target, then to the start the prompt names (``starts[word]``, an xy)."""

    stateful = False

    def __init__(self, starts: dict[str, tuple[float, float]], default: str, prompt_template: PromptTemplate,
                 field: str = "side", chunk_len: int = 8, gains: TouchGains | None = None,
                 carry: CarryGains | None = None):
        if default not in starts:
            raise ValueError(f"the default start {default!r} is not one of {sorted(starts)}")
        super().__init__(chunk_len, gains or TouchGains(max_x=REACH_X), vocabulary=tuple(starts), field=field, prompt_template=prompt_template,
                         key="target")
        self.starts = {word: np.asarray(xy, dtype=np.float64) for word, xy in starts.items()}
        self.default = default
        self.carry = carry or CarryGains()

    def start_of(self, parsed: ParsedPrompt) -> np.ndarray:
        """The start (xy) the prompt's first side fact names, or the default start without one."""
        word = named_word(parsed, self.field)
        return self.starts[word if word in self.starts else self.default]

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        extra = obs["extra"]
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        cube = as_numpy(extra["cube_position"]).astype(np.float64)
        targets = as_numpy(extra["target_positions"]).astype(np.float64)
        red_visible = as_numpy(extra["target_visible"]).astype(bool)[:, 0]
        qpos = as_numpy(obs["agent"]["qpos"]).astype(np.float64)
        velocity = tcp_velocity(qpos, as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            destination = targets[i, 0, :2] if red_visible[i] else self.start_of(p)
            goal = self._goal(tcp[i, :3], cube[i], qpos[i, 7:9].sum(), destination, returning=not red_visible[i])
            if goal is None:
                chunks[i, :, -1] = GRIP_CLOSED  # there: hold the cube still
            else:
                chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, goal)
        return chunks

    def _goal(self, pos: np.ndarray, cube: np.ndarray, gap: float, destination: np.ndarray,
              returning: bool) -> CarryGoal | None:
        c = self.carry
        held = c.held_gap[0] <= gap <= c.held_gap[1] and np.linalg.norm(pos - cube) <= c.held_reach
        if not held:
            return CarryGoal(cube.copy(), "grasp")
        if returning and np.linalg.norm(cube[:2] - destination) <= c.placed:
            return None
        hand = pos[:2] - cube[:2]  # the cube sits off the TCP in the fingers: steer the cube, not the TCP
        x = destination[0]
        if returning and abs(cube[1] - destination[1]) > c.level:
            x = max(x, min(cube[0], c.reach_x), c.return_lane)  # along the far side first, clear of the starts
        return CarryGoal(np.array([min(x + hand[0], c.reach_x), destination[1] + hand[1], c.carry_height]), "carry")

    def _waypoint(self, pos: np.ndarray, goal: Any) -> np.ndarray:
        """Grasping: the cube's centre, never below a funnel over it (the fingers come down from above).
        Carrying: straight to the point, rising first while the cube is low."""
        point = np.asarray(goal.point, dtype=np.float64)
        sideways = float(np.linalg.norm(point[:2] - pos[:2]))
        if goal.mode == "grasp":
            g = self.gains
            return np.array([point[0], point[1], point[2] + min(g.hover_height, g.funnel_slope * sideways)])
        if pos[2] < point[2] - self.carry.lift_first and sideways > self.carry.placed:
            return np.array([pos[0], pos[1], point[2]])
        return point

    def _grip(self, pos: np.ndarray, goal: Any) -> float:
        if goal.mode == "carry":
            return GRIP_CLOSED
        return GRIP_CLOSED if np.linalg.norm(pos - goal.point) <= self.carry.grasp_tol else GRIP_OPEN


__all__ = ["CarryBackController", "CarryGains", "CarryGoal", "GRIP_CLOSED", "GRIP_OPEN"]
