"""A scripted frozen controller for MIKASA's GatherAndRecall 1/3/5/7/9: put every cube on the disc, then press the
button of the colour the prompt names.

It stands in for a VLA finetuned on GatherAndRecall with the lamp's flash written into its prompt (``the flash was
green.``). It reads only what ``GatherObservation`` gives (joints, hand pose, where the cubes, the disc and the three
buttons are, the buttons by their colour), never the simulator, and keeps no state: every ``act`` re-reads the
observation and the prompt. The lamp is not in its view: the colour comes only from the prompt's first fact that
names one, whatever the fact is about (a decoy, ``the key was blue.``, misleads it as a wrong fact would). With none,
it presses its ``default`` button, a guess (success at chance, one in three).

Each cube has its own place on the disc (``place_targets``): the centre for one cube; else a ring of ``ring_radius``
round it (the layout MIKASA's motion-planning solution uses), with the first cube at the centre from ``RING_ALONE_MAX``
+ 1 cubes on, so that neighbours stay 1.7 cm apart or more (nine on one ring: 1.1 cm, and open fingers knocked them
off the disc). The cubes stand square to the table, so what parts two of them is the larger of their x and y offsets:
eight round the centre (nine cubes) go on a wider ring (``wide_ring_radius``), 2 cm apart rather than 1.3 cm, where a
lowered cube no longer comes to rest on its neighbour's edge; its place farthest from the arm stays ``ring_radius``
out (2 cm from its neighbours still), 1 cm nearer the edge of the arm's reach over a far disc. With several cubes
the fingers let go opening only part way (``release_grip``). Plan, each call, from what the observation shows:

- the hand low beside a cube resting on the disc: rise straight up first (open fingers sweeping sideways would push
  it off);
- holding a cube (fingers closed on a 4 cm gap, the TCP at it): lift it to the carry height (above the cubes already
  placed, where there are several) and carry it over its place, then lower it until it rests on the disc (its centre
  at ``REST_Z``), and open the fingers;
- a cube not yet on the disc (the first, in index order): come down a funnel over it with the gripper open and close
  it at the cube's centre (``CarryBackController``'s grasp);
- every cube resting on the disc: head for the named button down a funnel over it with the gripper closed, and hold
  the TCP ``press_height`` over its cap's top: MIKASA counts a press with the TCP within 4 cm of the button's axis and
  2.5 cm over the cap's top, once every cube is on the disc.

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
RING_ALONE_MAX = 5  # up to this many cubes all go on the ring; more: one at the centre, the rest on the ring
WIDE_RING_CUBES = 9  # this many or more: the ring is ``wide_ring_radius`` out


@dataclass(frozen=True)
class GatherGains:
    """Where the cube counts as placed, how the hand leaves it, and the press (metres)."""

    over_disc: float = 0.012  # lower the carried cube once its xy is this close to its place on the disc
    rest_margin: float = 0.006  # ... and open the fingers once its centre is this close to resting on the disc,
    hand_floor: float = 0.02  # ... or the TCP this low (a cube slipped up in the fingers, tilted, goes no lower)
    ring_radius: float = 0.075  # several cubes' places: a ring this far from the disc's centre (MIKASA's solution)
    wide_ring_radius: float = 0.085  # ... and for eight round the centre (nine cubes; the far place: ring_radius)
    placed_radius: float = 0.06  # a cube resting this close to its place is placed ...
    on_disc_radius: float = 0.097  # ... and this close to the disc's centre (MIKASA counts it on within 10 cm)
    stack_clearance: float = 0.10  # several cubes: carry at least this high (centre), over the placed ones' tops
    release_grip: float = 0.5  # ... and let go opening to this command (about 5.5 cm between the fingers)
    resting: float = 0.035  # a cube centre lower than this rests (on the disc: 2.6 cm; held up: higher)
    clear_radius: float = 0.06  # the hand this close to the placed cube sideways ...
    clear_height: float = 0.10  # ... and lower than this: rise straight up first
    press_height: float = 0.012  # the TCP over the cap's top when pressing (MIKASA: within 2.5 cm)


def place_targets(disc: np.ndarray, n_cubes: int, ring_radius: float, farthest: float = np.inf) -> np.ndarray:
    """Where each of ``n_cubes`` cubes is set down on the disc whose centre is ``disc`` (3,): (n_cubes, 2) xy, none
    more than ``farthest`` beyond the centre in x (away from the arm's base)."""
    if n_cubes < 1:
        raise ValueError(f"n_cubes must be at least 1, got {n_cubes}")
    centre = np.asarray(disc, dtype=np.float64)[None, :2]
    if n_cubes == 1:
        return centre.copy()
    on_ring = n_cubes if n_cubes <= RING_ALONE_MAX else n_cubes - 1
    angles = np.pi / 2 + 2 * np.pi * np.arange(on_ring) / on_ring
    ring = centre + ring_radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    ring[:, 0] = np.minimum(ring[:, 0], centre[0, 0] + farthest)
    return ring if on_ring == n_cubes else np.concatenate([centre, ring])


class GatherGoal(NamedTuple):
    """Where a chunk heads and how: ``grasp`` (down a funnel onto ``point``, closing there), ``carry`` (closed,
    rising first to ``height`` while low), ``release`` (opening to ``grip``, in place), ``rise`` (as open, straight)
    or ``press`` (closed, down a funnel onto ``point``)."""

    point: np.ndarray
    mode: str
    height: float = 0.0
    grip: float = GRIP_OPEN


class GatherPressController(ScriptedTouchController):
    """Puts every cube on the disc, then presses the button whose colour the prompt names (``vocabulary[i]`` names
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
        cubes = as_numpy(extra["cube_positions"]).astype(np.float64)
        disc = as_numpy(extra["disc_position"]).astype(np.float64)
        buttons = as_numpy(extra["button_positions"]).astype(np.float64)
        qpos = as_numpy(obs["agent"]["qpos"]).astype(np.float64)
        velocity = tcp_velocity(qpos, as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            button = buttons[i, self.vocabulary.index(self.colour_of(p))]
            goal = self._goal(tcp[i, :3], cubes[i], qpos[i, 7:9].sum(), disc[i], button)
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, goal)
        return chunks

    def _goal(self, pos: np.ndarray, cubes: np.ndarray, gap: float, disc: np.ndarray,
              button: np.ndarray) -> GatherGoal:
        c, g = self.carry, self.gather
        wide = len(cubes) >= WIDE_RING_CUBES
        targets = place_targets(disc, len(cubes), g.wide_ring_radius if wide else g.ring_radius, g.ring_radius)
        grip = GRIP_OPEN if len(cubes) == 1 else g.release_grip
        off_place = np.linalg.norm(cubes[:, :2] - targets, axis=1)
        off_centre = np.linalg.norm(cubes[:, :2] - disc[None, :2], axis=1)
        placed = (off_place <= g.placed_radius) & (off_centre <= g.on_disc_radius) & (cubes[:, 2] <= g.resting)
        reach = np.linalg.norm(cubes - pos, axis=1)
        held = int(reach.argmin())
        if c.held_gap[0] <= gap <= c.held_gap[1] and reach[held] <= c.held_reach:
            cube, target = cubes[held], targets[held]
            if off_place[held] <= g.over_disc and (cube[2] <= REST_Z + g.rest_margin or pos[2] <= g.hand_floor):
                return GatherGoal(pos.copy(), "release", grip=grip)
            hand = pos - cube  # the cube sits off the TCP in the fingers: steer the cube, not the TCP
            # over the placed cubes' tops where there are several
            lift = c.carry_height if len(cubes) == 1 else max(c.carry_height, g.stack_clearance)
            height = REST_Z if off_place[held] <= g.over_disc else lift
            return GatherGoal(np.array([target[0], target[1], height]) + hand, "carry", lift)
        beside = np.linalg.norm(cubes[placed, :2] - pos[:2], axis=1) < g.clear_radius
        if beside.any() and pos[2] < g.clear_height:
            return GatherGoal(np.array([pos[0], pos[1], g.clear_height + 0.02]), "rise", grip=grip)
        if not placed.all():
            return GatherGoal(cubes[int(np.flatnonzero(~placed)[0])].copy(), "grasp")
        return GatherGoal(button + (0.0, 0.0, BUTTON_TOP_ABOVE_BASE + g.press_height), "press")

    def _waypoint(self, pos: np.ndarray, goal: Any) -> np.ndarray:
        """Grasping and pressing: the goal's point, never below a funnel over it (the hand comes down from above).
        Carrying: straight there, rising first while the cube is low and far off. Rising, releasing: the point.

        The grasp's funnel is flat within ``arrive_tol`` of the cube's axis: the hand stops once within
        ``arrive_tol`` of its waypoint, and a funnel that rose from the axis could stop it there short of
        ``grasp_tol`` (6 mm aside, 12 mm over the centre), open over the cube for the rest of the episode."""
        point = np.asarray(goal.point, dtype=np.float64)
        sideways = float(np.linalg.norm(point[:2] - pos[:2]))
        if goal.mode in ("grasp", "press"):
            g = self.gains
            if goal.mode == "grasp":
                sideways = max(0.0, sideways - g.arrive_tol)
            return np.array([point[0], point[1], point[2] + min(g.hover_height, g.funnel_slope * sideways)])
        if goal.mode == "carry" and pos[2] < goal.height - self.carry.lift_first and sideways > self.gather.over_disc:
            return np.array([pos[0], pos[1], goal.height])
        return point

    def _grip(self, pos: np.ndarray, goal: Any) -> float:
        if goal.mode in ("carry", "press"):
            return GRIP_CLOSED
        if goal.mode == "grasp":
            return GRIP_CLOSED if np.linalg.norm(pos - goal.point) <= self.carry.grasp_tol else GRIP_OPEN
        return goal.grip


__all__ = ["BUTTON_TOP_ABOVE_BASE", "GatherGains", "GatherGoal", "GatherPressController", "REST_Z", "RING_ALONE_MAX",
           "WIDE_RING_CUBES", "place_targets"]
