"""A scripted frozen controller for MIKASA's GatherAndRecall1: put the cube on the disc, then press the button of the
colour the prompt names.

It stands in for a VLA finetuned on GatherAndRecall with the lamp's flash written into its prompt (``the flash was
green.``). It reads only what ``GatherObservation`` gives (joints, hand pose, where the cube, the disc and the three
buttons are, the buttons by their colour), never the simulator, and keeps no state: every ``act`` re-reads the
observation and the prompt. The lamp is not in its view: the colour comes only from the prompt's first fact that
names one, whatever the fact is about (a decoy, ``the key was blue.``, misleads it as a wrong fact would). With none,
it presses its ``default`` button, a guess (success at chance, one in three).

Plan, each call, from what the observation shows:

- the cube not in the fingers and not on the disc: come down a funnel over it with the gripper open and close it at
  the cube's centre (``CarryBackController``'s grasp);
- holding it (fingers closed on a 4 cm gap, the TCP at the cube): lift it to ``carry_height`` and carry it over the
  disc's centre, then lower it until it rests on the disc (its centre at ``REST_Z``), and open the fingers;
- the cube resting on the disc and out of the fingers: rise straight up while the hand is low beside it (open fingers
  sweeping sideways would push it off), then head for the named button down a funnel over it with the gripper
  closed, and hold the TCP ``press_height`` over its cap's top: MIKASA counts a press with the TCP within 4 cm of the
  button's axis and 2.5 cm over the cap's top, once the cube is on the disc.

Motion within a chunk uses ``ScriptedTouchController``'s fitted model of the ``pd_ee_delta_pose`` arm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.carry_expert import GRIP_CLOSED, GRIP_OPEN, CarryGains
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT, ScriptedTouchController, TouchGains, named_word, tcp_velocity

# MIKASA's GatherAndRecallVLABaseEnv geometry: a disc 3 mm high, a 4 cm cube, buttons whose base (3 cm high) carries
# a 2.8 cm cap, so the cap's top is 4.3 cm over the base's centre (the detector's point)
REST_Z = 0.026  # the cube's centre resting on the disc
BUTTON_TOP_ABOVE_BASE = 0.043


@dataclass(frozen=True)
class GatherGains:
    """Where the cube counts as placed, how the hand leaves it, and the press (metres)."""

    over_disc: float = 0.012  # lower the carried cube once its xy is this close to the disc's centre
    rest_margin: float = 0.006  # ... and open the fingers once its centre is this close to resting on the disc
    placed_radius: float = 0.06  # a cube resting this close to the disc's centre is placed (MIKASA: 10 cm)
    resting: float = 0.035  # a cube centre lower than this rests (on the disc: 2.6 cm; held up: higher)
    clear_radius: float = 0.06  # the hand this close to the placed cube sideways ...
    clear_height: float = 0.10  # ... and lower than this: rise straight up first
    press_height: float = 0.012  # the TCP over the cap's top when pressing (MIKASA: within 2.5 cm)


class GatherGoal(NamedTuple):
    """Where a chunk heads and how: ``grasp`` (down a funnel onto ``point``, closing there), ``carry`` (closed,
    rising first while low), ``release`` (open, in place), ``rise`` (open, straight) or ``press`` (closed, down a
    funnel onto ``point``)."""

    point: np.ndarray
    mode: str


class GatherPressController(ScriptedTouchController):
    """Puts the cube on the disc, then presses the button whose colour the prompt names (``vocabulary[i]`` names
    button i of the detector); ``default``: the colour it presses without a fact."""

    stateful = False

    def __init__(self, prompt_template: PromptTemplate, vocabulary: Sequence[str], default: str,
                 chunk_len: int = 8, gains: TouchGains | None = None, carry: CarryGains | None = None,
                 gather: GatherGains | None = None):
        super().__init__(chunk_len, gains, vocabulary=vocabulary, field="colour", prompt_template=prompt_template,
                         key="button", default=default)
        self.carry = carry or CarryGains()
        self.gather = gather or GatherGains()

    def colour_of(self, parsed: ParsedPrompt) -> str:
        """The colour of the prompt's first fact that names one it knows, or the default guess."""
        word = named_word(parsed, self.field)
        return word if word in self.vocabulary else self.default

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        extra = obs["extra"]
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        cube = as_numpy(extra["cube_position"]).astype(np.float64)
        disc = as_numpy(extra["disc_position"]).astype(np.float64)
        buttons = as_numpy(extra["button_positions"]).astype(np.float64)
        qpos = as_numpy(obs["agent"]["qpos"]).astype(np.float64)
        velocity = tcp_velocity(qpos, as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            button = buttons[i, self.vocabulary.index(self.colour_of(p))]
            goal = self._goal(tcp[i, :3], cube[i], qpos[i, 7:9].sum(), disc[i], button)
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, goal)
        return chunks

    def _goal(self, pos: np.ndarray, cube: np.ndarray, gap: float, disc: np.ndarray,
              button: np.ndarray) -> GatherGoal:
        c, g = self.carry, self.gather
        held = c.held_gap[0] <= gap <= c.held_gap[1] and np.linalg.norm(pos - cube) <= c.held_reach
        off_centre = float(np.linalg.norm(cube[:2] - disc[:2]))
        if held:
            if off_centre <= g.over_disc and cube[2] <= REST_Z + g.rest_margin:
                return GatherGoal(pos.copy(), "release")
            hand = pos - cube  # the cube sits off the TCP in the fingers: steer the cube, not the TCP
            height = REST_Z if off_centre <= g.over_disc else c.carry_height
            return GatherGoal(np.array([disc[0], disc[1], height]) + hand, "carry")
        if off_centre > g.placed_radius or cube[2] > g.resting:
            return GatherGoal(cube.copy(), "grasp")
        if np.linalg.norm(pos[:2] - cube[:2]) < g.clear_radius and pos[2] < g.clear_height:
            return GatherGoal(np.array([pos[0], pos[1], g.clear_height + 0.02]), "rise")
        return GatherGoal(button + (0.0, 0.0, BUTTON_TOP_ABOVE_BASE + g.press_height), "press")

    def _waypoint(self, pos: np.ndarray, goal: Any) -> np.ndarray:
        """Grasping and pressing: the goal's point, never below a funnel over it (the hand comes down from above).
        Carrying: straight there, rising first while the cube is low and far off. Rising, releasing: the point."""
        point = np.asarray(goal.point, dtype=np.float64)
        sideways = float(np.linalg.norm(point[:2] - pos[:2]))
        if goal.mode in ("grasp", "press"):
            g = self.gains
            return np.array([point[0], point[1], point[2] + min(g.hover_height, g.funnel_slope * sideways)])
        if goal.mode == "carry" and pos[2] < self.carry.carry_height - self.carry.lift_first \
                and sideways > self.gather.over_disc:
            return np.array([pos[0], pos[1], self.carry.carry_height])
        return point

    def _grip(self, pos: np.ndarray, goal: Any) -> float:
        if goal.mode in ("carry", "press"):
            return GRIP_CLOSED
        if goal.mode == "grasp":
            return GRIP_CLOSED if np.linalg.norm(pos - goal.point) <= self.carry.grasp_tol else GRIP_OPEN
        return GRIP_OPEN


__all__ = ["BUTTON_TOP_ABOVE_BASE", "GatherGains", "GatherGoal", "GatherPressController", "REST_Z"]
