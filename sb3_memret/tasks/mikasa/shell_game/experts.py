"""The ShellGame experts: scripted controllers that touch or push the cup their prompt names."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.carry_expert import GRIP_CLOSED, REACH_X
from sb3_memret.tasks.mikasa.core.touch_expert import (CONTROL_DT, ScriptedTouchController, TouchGains, named_word,
                                                       tcp_velocity)
from sb3_memret.tasks.mikasa.shell_game.variants import DEFAULT_SIDE, LAMP_COLOURS, SIDES, ball_entity


@dataclass(frozen=True)
class CupGains:
    """The cup's geometry as the experts assume it (estimated: the mug was never loaded here) and the push."""

    clearance: float = 0.02  # TCP above the cup's top at a touch (the fingertips reach 9 mm lower)
    max_above: float = 0.072  # TCP at most this far above the cup's centre (MIKASA's touch: within 8 cm of it)
    push_distance: float = 0.1  # push the cup this far in front of the row (MIKASA's hidden goal: 10 cm)
    contact: float = 0.06  # TCP this far behind a cup's centre when pushing it (the mug's radius ~5 cm + a finger)
    backoff: float = 0.11  # start a push from this far behind the cup's centre, clear of its handle
    align: float = 0.015  # the TCP within this of the cup's y (and of the push height) is lined up to push
    pushed: float = 0.02  # the cup within this of the push distance: done, hold still



class CupTouchController(ScriptedTouchController):
    """Touches the cup the prompt's fact names (``the ball is under the left cup.``): its TCP comes down a funnel
    onto a point ``clearance`` above the cup's top and holds still. With ``colours`` (the ColorLamp tasks) the fact
    is the one about the ball of the lamp's colour (``extra/lamp_visible``), and it waits while the lamp is white.
    Without a fact it touches its ``default`` cup, a guess. Stateless: every call re-reads the observation and
    the prompt. The cup's top is taken to lie twice its centre's height up (MIKASA rests a cup at minus its mesh's
    lowest point, its half-height for ManiSkill's centred YCB meshes)."""

    stateful = False

    def __init__(self, prompt_template: PromptTemplate, colours: tuple[str, ...] = (), default: str = DEFAULT_SIDE,
                 chunk_len: int = 8, gains: TouchGains | None = None, cup: CupGains | None = None):
        super().__init__(chunk_len, gains or TouchGains(max_x=REACH_X, ready=(-0.05, 0.0, 0.3)), vocabulary=SIDES,
                         field="side", prompt_template=prompt_template, key="cup", default=default)
        unknown = sorted(set(colours) - set(LAMP_COLOURS))
        if unknown:
            raise ValueError(f"unknown ball colours {unknown}; expected some of {list(LAMP_COLOURS)}")
        self.colours, self.cup = tuple(colours), cup or CupGains()

    def side_of(self, parsed: ParsedPrompt, lamp: np.ndarray | None) -> str | None:
        """The cup to act on: the side the prompt's fact names (the fact about the lamp's colour with ``colours``),
        the default without one; None while the lamp is white."""
        if not self.colours:
            word = named_word(parsed, self.field)
        else:
            lit = [c for c, on in zip(LAMP_COLOURS, lamp) if on] if lamp is not None else []
            if len(lit) != 1:
                return None
            wanted = ball_entity(lit[0], len(self.colours))
            facts = [dict(fact.fields) for fact in parsed.facts]
            word = next((fields.get("side") for fields in facts if fields.get("entity") == wanted), None)
        return word if word in self.vocabulary else self.default

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        extra = obs["extra"]
        if self.colours and "lamp_visible" not in extra:
            raise ValueError("the ColorLamp expert reads the lamp (extra/lamp_visible): wrap the env in "
                             "LampCupObservation")
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        cups = as_numpy(extra["cup_positions"]).astype(np.float64)
        visible = as_numpy(extra["cup_visible"]).astype(bool)
        lamps = as_numpy(extra["lamp_visible"]).astype(bool) if self.colours else [None] * len(prompts)
        velocity = tcp_velocity(as_numpy(obs["agent"]["qpos"]), as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            side = self.side_of(p, lamps[i])
            goal = None
            if side is not None and visible[i].all():  # the detector orders the cups left to right once all are down
                goal = self._goal(tcp[i, :3], cups[i], SIDES.index(side))
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, goal)
        return chunks

    def _goal(self, tcp: np.ndarray, cups: np.ndarray, index: int) -> Any:
        """What a chunk heads for: the cup ``index`` (of the row ``cups``, (3, 3) left to right)."""
        return cups[index]

    def touch_point(self, cup: np.ndarray) -> np.ndarray:
        """Where the TCP touches ``cup`` (its centre): above its top by ``clearance``, within ``max_above`` of it."""
        c = self.cup
        return np.array([cup[0], cup[1], cup[2] + min(cup[2] + c.clearance, c.max_above)])

    def _waypoint(self, pos: np.ndarray, cup: np.ndarray | None) -> np.ndarray:
        """Down a funnel over the touch point (the lowest it may be rises with the distance sideways), never back
        up it; the ready pose while no cup is to be touched."""
        g = self.gains
        if cup is None:
            return np.asarray(g.ready, dtype=np.float64)
        touch = self.touch_point(cup)
        floor = touch[2] + min(g.hover_height, g.funnel_slope * float(np.linalg.norm(touch[:2] - pos[:2])))
        return np.array([touch[0], touch[1], max(touch[2], min(pos[2], floor))])



class PushGoal(NamedTuple):
    """A push chunk's aim: ``approach`` (down a funnel to ``point``, behind the cup), ``push`` (straight to
    ``point``, the cup ahead) or ``hold`` (the cup is there: stay still)."""

    point: np.ndarray
    mode: str



class CupPushController(CupTouchController):
    """Pushes the cup the prompt's fact names forward (+x, away from the robot) by ``push_distance``: it comes down
    behind the cup at the height of its centre, fingers closed, drives forward until the cup stands that far in
    front of the other two (the row it left), then holds still. Without a fact it pushes the default cup."""

    def _goal(self, tcp: np.ndarray, cups: np.ndarray, index: int) -> PushGoal:
        c = self.cup
        cup = cups[index]
        row_x = float(np.mean(np.delete(cups[:, 0], index)))  # the cups left standing mark the row
        height = max(cup[2], 0.03)
        if cup[0] - row_x >= c.push_distance - c.pushed:
            return PushGoal(tcp.copy(), "hold")
        lined_up = abs(tcp[1] - cup[1]) <= c.align and abs(tcp[2] - height) <= c.align and tcp[0] < cup[0]
        if lined_up:
            return PushGoal(np.array([row_x + c.push_distance - c.contact, cup[1], height]), "push")
        return PushGoal(np.array([cup[0] - c.backoff, cup[1], height]), "approach")

    def _waypoint(self, pos: np.ndarray, goal: PushGoal | None) -> np.ndarray:
        g = self.gains
        if goal is None:
            return np.asarray(g.ready, dtype=np.float64)
        if goal.mode == "hold":
            return pos.copy()
        if goal.mode == "push":
            return goal.point
        point = goal.point
        floor = point[2] + min(g.hover_height, g.funnel_slope * float(np.linalg.norm(point[:2] - pos[:2])))
        return np.array([point[0], point[1], max(point[2], min(pos[2], floor))])

    def _grip(self, pos: np.ndarray, goal: Any) -> float:
        return GRIP_CLOSED  # a closed hand pushes as one block


__all__ = ["CupGains", "CupPushController", "CupTouchController", "PushGoal"]
