"""A scripted frozen controller for MIKASA's TimedTransfer: hold the blue cube over the red disc, and set it on the
disc when the prompt's count reaches the step the instruction names.

It stands in for a VLA finetuned on TimedTransfer with the time since the lamp turned green written into its prompt
(``the lamp turned green 96 steps ago.``): the delay comes from its instruction (``... exactly on step 100 of that
count.``), the count only from the prompt's first fact that carries one, whatever the fact is about (a decoy, ``the
key turned green 40 steps ago.``, misleads it as a wrong fact would). It keeps no state and has no clock of its own:
every ``act`` re-reads the observation and the prompt, as a memoryless VLA would. Without a count it holds the cube
over the red disc and never sets it down (a guess that cannot succeed: it cannot tell the step).

It reads only what ``TimedTransferObservation`` gives (joints, hand pose, the cube's and the two discs' positions,
as a detector reports them), never the simulator. Plan, each call:

- the cube not in its fingers: come down a funnel over it with the gripper open and close it at the cube's centre
  (``CarryBackController``'s grasp);
- holding it: carry it over the red disc with its centre at ``hover_z`` (above MIKASA's 6.6 cm, where the cube
  does not yet count as on the disc) and hold it there;
- once the count is within ``lead`` steps of the delay: lower it to ``place_z``, where it counts as on the disc (its
  xy within 5 cm of the disc's centre); MIKASA's window holds the counts from 95% to 105% of the delay.

Motion within a chunk uses ``ScriptedTouchController``'s fitted model of the ``pd_ee_delta_pose`` arm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.carry_expert import GRIP_CLOSED, GRIP_OPEN, CarryGains
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT, ScriptedTouchController, TouchGains, tcp_velocity


@dataclass(frozen=True)
class TimedGains:
    """The hover, the drop and its timing (metres, control steps)."""

    hover_z: float = 0.09  # the held cube's centre while waiting over the red disc (MIKASA: on it below 6.6 cm)
    place_z: float = 0.045  # ... and once it is time (4.5 cm: its bottom 0.2 cm over the disc's top)
    over_disc: float = 0.015  # the cube's xy this close to the disc's centre: over it
    lead: int = 3  # start lowering this many steps before the delay (it takes about two)


class TimedGoal(NamedTuple):
    """Where a chunk heads and how: ``grasp`` (down a funnel onto ``point``, closing there) or ``carry``."""

    point: np.ndarray
    mode: str


class TimedTransferController(ScriptedTouchController):
    """Carries the blue cube over the red disc and sets it down on the step its instruction names, counting from its
    prompt's fact (field ``count``; the instruction's field ``delay``)."""

    stateful = False

    def __init__(self, prompt_template: PromptTemplate, chunk_len: int = 8, gains: TouchGains | None = None,
                 carry: CarryGains | None = None, timing: TimedGains | None = None):
        super().__init__(chunk_len, gains, vocabulary=("lamp",), field="count", prompt_template=prompt_template,
                         key="disc")
        self.carry = carry or CarryGains()
        self.timing = timing or TimedGains()

    def due(self, parsed: ParsedPrompt) -> bool:
        """Whether the prompt says it is time to set the cube down: its first count within ``lead`` of the delay."""
        delay = dict(parsed.instruction_fields).get("delay")
        if delay is None:
            raise ValueError(f"instruction {parsed.instruction!r} names no delay (field 'delay'); the TimedTransfer "
                             "expert needs its instruction's step")
        count = parsed.field(self.field)
        return count is not None and int(count) >= int(delay) - self.timing.lead

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        extra = obs["extra"]
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        cube = as_numpy(extra["cube_position"]).astype(np.float64)
        red = as_numpy(extra["disc_positions"]).astype(np.float64)[:, 1]  # (green, red)
        qpos = as_numpy(obs["agent"]["qpos"]).astype(np.float64)
        velocity = tcp_velocity(qpos, as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            goal = self._goal(tcp[i, :3], cube[i], qpos[i, 7:9].sum(), red[i], self.due(p))
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, goal)
        return chunks

    def _goal(self, pos: np.ndarray, cube: np.ndarray, gap: float, red: np.ndarray, due: bool) -> TimedGoal:
        c, g = self.carry, self.timing
        held = c.held_gap[0] <= gap <= c.held_gap[1] and np.linalg.norm(pos - cube) <= c.held_reach
        if not held:
            return TimedGoal(cube.copy(), "grasp")
        over = np.linalg.norm(cube[:2] - red[:2]) <= g.over_disc
        height = g.place_z if due and over else g.hover_z
        hand = pos - cube  # the cube sits off the TCP in the fingers: steer the cube, not the TCP
        return TimedGoal(np.array([red[0], red[1], height]) + hand, "carry")

    def _waypoint(self, pos: np.ndarray, goal: Any) -> np.ndarray:
        """Grasping: the cube's centre, never below a funnel over it. Carrying: straight to the point, rising first
        while the cube is low and away from it."""
        point = np.asarray(goal.point, dtype=np.float64)
        sideways = float(np.linalg.norm(point[:2] - pos[:2]))
        if goal.mode == "grasp":
            g = self.gains
            return np.array([point[0], point[1], point[2] + min(g.hover_height, g.funnel_slope * sideways)])
        if pos[2] < point[2] - self.carry.lift_first and sideways > self.timing.over_disc:
            return np.array([pos[0], pos[1], point[2]])
        return point

    def _grip(self, pos: np.ndarray, goal: Any) -> float:
        if goal.mode == "carry":
            return GRIP_CLOSED
        return GRIP_CLOSED if np.linalg.norm(pos - goal.point) <= self.carry.grasp_tol else GRIP_OPEN


__all__ = ["TimedGains", "TimedGoal", "TimedTransferController"]
