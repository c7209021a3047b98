"""A scripted frozen controller for MIKASA's Rotate tasks: turn the peg to the angle its prompt sets.

It stands in for a VLA finetuned on Rotate with the peg's start angle written into its prompt (``rotate the peg by
38 degrees to match the target angle. the peg started at 35 degrees.``). The rotation comes only from the
instruction (its ``angle_deg``), the start only from the prompt's first fact that names one (``start_deg``, whatever
the fact is about: a decoy, ``the key started at 57 degrees.``, misleads it as a wrong fact would); with none it
takes the peg to have started at ``default_start_deg``, a guess, so without memory it succeeds only where the peg
happened to lie near that angle. It reads only what ``RotateObservation`` gives (joints, hand pose, the peg's centre
and the angle of its axis as a detector reports them, ends alike) and keeps no state: every ``act`` re-reads the
observation and the prompt, so the angle the peg has turned through is never counted, only where it lies now.

**The goal.** The peg must end at ``start + rotation`` (its axis, modulo 180 degrees). What is left to turn is that
goal minus the peg's angle now, taken in the half-turn window centred on ``rotation / 2``: the whole rotation at the
start, zero at the goal, so a rotation of up to 90 degrees either way turns the way the instruction says.

**Two ways to turn it** (``strategy``):

- ``grasp`` (Strict's 90 steps: the peg's centre must stay within 5 cm): come down over the peg's centre with the
  fingers open across its width, the hand turned to its axis, close, lift it 2 cm off the table and turn the hand
  until the peg lies at its goal, then hold still. The hand turns at most 2.25 degrees a control step (measured: a
  full rotation action, ``pd_ee_delta_pose``), so lining the fingers up (up to 90 degrees) and the turn (up to 90)
  can take 80 steps: more than Lenient's 60. Of the two alignments of the fingers (half a turn apart) it takes the
  nearer one that the wrist's last joint can then turn through.
- ``push`` (Lenient's 60 steps: only the angle counts): with the fingers closed, come down behind one end of the peg
  and push that end sideways, which turns the peg up to 7 degrees a step (and slides it nearly as far as the push),
  slowing as the goal nears, then hold still. Of the two ends it pushes the one whose push would end nearer the
  table's middle and inside the arm's reach (a peg slid beyond x ~ 0.15 m can no longer be pushed back), weighed
  against the way to get behind it, so it keeps pushing the end it is at; after an overshoot it comes round to the
  other side.

Motion within a chunk uses ``ScriptedTouchController``'s fitted model of the ``pd_ee_delta_pose`` arm (the TCP's
step and its coasting); the hand turns ``TURN_GAIN`` of a commanded rotation a step and stops when the command does.
Holding still is an all-zero motion command, after which the arm is static (MIKASA's success needs it) at the next
step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from sb3_memret.controllers.base import ControllerSpec, FrozenController, Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.touch_expert import (
    COAST_GAIN, CONTROL_DT, DRIVE_GAIN, POS_SCALE, R_DOWN, ROT_SCALE, TURN_GAIN, named_word, tcp_velocity,
)

GRIP_OPEN, GRIP_CLOSED = 1.0, -1.0
STRATEGIES = ("grasp", "push")
PEG_HALF_WIDTH, PEG_HALF_LENGTH = 0.025, 0.12  # MIKASA's peg (m)
WRIST_LIMIT = 2.8  # rad: the Panda's last joint reaches +-2.8973; the hand's angle turns against it, one for one


def wrap(angle: float | np.ndarray, period: float = np.pi) -> Any:
    """``angle`` wrapped into [-period / 2, period / 2)."""
    return (np.asarray(angle) + period / 2) % period - period / 2


def remaining_turn(goal: float, yaw: float, rotation: float) -> float:
    """What is left to turn (radians, signed, counter-clockwise positive) from the peg's axis angle ``yaw`` to ``goal``
    (both modulo pi), in the half-turn window centred on ``rotation / 2``: ``rotation`` at the start, 0 at the goal."""
    return float(wrap(goal - yaw - rotation / 2) + rotation / 2)


def hand_yaw(rotation: Rotation) -> float:
    """The angle of the hand's x axis (along the fingers' pads) about the vertical, radians."""
    matrix = rotation.as_matrix()
    return float(np.arctan2(matrix[1, 0], matrix[0, 0]))


@dataclass(frozen=True)
class TurnGains:
    """The motion (metres, radians, per control step) and the geometry of grasping and pushing the peg."""

    max_step: float = 0.039  # per axis: a full translation action's steady-state step
    approach_gain: float = 0.7  # plan a step of this fraction of the remaining distance
    max_turn: float = TURN_GAIN * abs(ROT_SCALE)  # the hand's turn at a full rotation action (2.25 degrees)
    done: float = np.radians(1.5)  # the peg this close to its goal: hold still (MIKASA's tolerance is 5.7 degrees)
    hover: float = 0.08  # TCP height to travel at, clear of the peg (its top is at 5 cm)
    funnel_slope: float = 1.2  # coming down: the lowest the TCP may be above its point, per metre sideways
    # grasping
    grasp_z: float = 0.022  # TCP height to close at (the peg's centre is at 2.5 cm)
    clear_z: float = 0.07  # the lowest the TCP may be over the peg before the fingers are turned to it
    align_tol: float = np.radians(6)  # the hand this close to the peg's axis before the fingers come down
    over_tol: float = 0.008  # the TCP this close to the peg's centre (xy) before the fingers come down
    close_tol: float = 0.01  # ... and this close to the grasp point: close the fingers
    held_gap: tuple[float, float] = (0.04, 0.056)  # the fingers' gap when closed on the 5 cm peg ...
    held_reach: float = 0.025  # ... with the TCP this close to the peg's centre: the peg is in hand
    lift_z: float = 0.045  # the TCP's height while turning the peg in hand (2 cm off the table)
    # pushing
    lever: float = 0.105  # push the peg this far from its centre along its axis (its ends are at 12 cm)
    push_z: float = 0.02  # TCP height while pushing
    standoff: float = 0.015  # start a push this far behind the peg's face (beyond the fingers' 12 mm half-width)
    finger: float = 0.012  # the closed fingers' half-width across the push
    push_funnel: float = 3.0  # getting behind the peg: the lowest the TCP may be above push_z, per metre sideways
    turn_per_metre: float = 6.0  # rad the peg turns per metre pushed (measured: 4.5-7)
    push_fraction: float = 0.15  # per step, push for this fraction of what is left to turn
    push_speed: tuple[float, float] = (0.002, 0.02)  # the push's step, least and most
    home: tuple[float, float] = (-0.05, 0.0)  # of the two ends, push the one whose push ends nearer here ...
    home_weight: float = 1.0  # ... weighed against the way to get behind it (m per m)
    # (x, y) bounds of where a push starts (the arm pointing down reaches x ~0.19 m) and where it ends (far enough in
    # for a push back from beyond the peg); per metre outside, a push costs reach_weight
    start_reach: tuple[tuple[float, float], tuple[float, float]] = ((-0.2, 0.15), (-0.3, 0.3))
    finish_reach: tuple[tuple[float, float], tuple[float, float]] = ((-0.2, 0.08), (-0.25, 0.25))
    reach_weight: float = 10.0


class Plan(NamedTuple):
    """Where the TCP heads at one step of a chunk, the hand's angle (None: keep it), and the gripper."""

    point: np.ndarray
    yaw: float | None
    grip: float


class PegTurnController(FrozenController):
    """Turns the peg to ``start + rotation``: the rotation from its prompt's instruction, the start from its first
    ``start_deg`` fact (``default_start_deg`` without one), by grasping or pushing (``strategy``)."""

    stateful = False

    def __init__(self, prompt_template: PromptTemplate, strategy: str, default_start_deg: float = 0.0,
                 chunk_len: int = 8, gains: TurnGains | None = None):
        if strategy not in STRATEGIES:
            raise ValueError(f"unknown strategy {strategy!r}; expected one of {list(STRATEGIES)}")
        self.strategy, self.default_start = strategy, np.radians(default_start_deg)
        self.gains = gains or TurnGains()
        self.spec = ControllerSpec(action_convention="pd_ee_delta_pose", chunk_len=chunk_len, action_dim=7,
                                   prompt_template=prompt_template)
        self._batch = 0

    def reset(self, seeds: Sequence[int]) -> None:
        self._batch = len(seeds)

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        self._check_env_ids(env_ids, seeds, self._batch)

    def goal_of(self, parsed: ParsedPrompt) -> tuple[float, float]:
        """The rotation the instruction names and the start the prompt's first start fact names (radians)."""
        fields = dict(parsed.instruction_fields)
        if "angle_deg" not in fields:
            raise ValueError(f"instruction {parsed.instruction!r} names no rotation (an {{angle_deg}} field); "
                             f"expected one of {self.spec.prompt_template.describe()}")
        start = named_word(parsed, "start_deg")
        return np.radians(int(fields["angle_deg"])), self.default_start if start is None else np.radians(int(start))

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        extra = obs["extra"]
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        centre = as_numpy(extra["peg_positions"]).astype(np.float64)[:, 0]
        yaw = as_numpy(extra["peg_yaw"]).astype(np.float64).reshape(-1)
        qpos = as_numpy(obs["agent"]["qpos"]).astype(np.float64)
        velocity = tcp_velocity(qpos, as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            rotation, start = self.goal_of(p)
            left = remaining_turn(start + rotation, yaw[i], rotation)
            if abs(left) <= self.gains.done:
                chunks[i, :, -1] = GRIP_CLOSED  # there: hold still
                continue
            plan = self._grasp_plan if self.strategy == "grasp" else self._push_plan
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT,
                                    plan(tcp[i], centre[i], yaw[i], left, qpos[i]))
        return chunks

    # ------------------------------------------------------------ grasping
    def _grasp_plan(self, tcp: np.ndarray, centre: np.ndarray, yaw: float, left: float,
                    qpos: np.ndarray) -> Callable[[np.ndarray, float], Plan | None]:
        """Grasp the peg at its centre, lift it, turn the hand by ``left``; or, in hand, the turn alone."""
        g = self.gains
        pos, hand = tcp[:3], hand_yaw(Rotation.from_quat(tcp[[4, 5, 6, 3]]))
        gap = qpos[7] + qpos[8]
        held = g.held_gap[0] <= gap <= g.held_gap[1] and np.linalg.norm(pos - centre) <= g.held_reach
        if held:
            goal_yaw, hold_at = hand + left, np.array([pos[0], pos[1], g.lift_z])

            def turn(p: np.ndarray, h: float) -> Plan | None:
                if abs(goal_yaw - h) <= g.done / 4:
                    return None
                return Plan(hold_at, goal_yaw, GRIP_CLOSED)

            return turn
        aligned_yaw = self._finger_yaw(hand, yaw, left, qpos[6])
        grasp_point = np.array([centre[0], centre[1], g.grasp_z])

        def grasp(p: np.ndarray, h: float) -> Plan:
            sideways = float(np.linalg.norm(grasp_point[:2] - p[:2]))
            aligned = abs(wrap(h - aligned_yaw)) <= g.align_tol
            if sideways > g.over_tol or not aligned:  # above the peg first, the fingers clear of its top
                floor = max(g.grasp_z + min(g.hover, g.funnel_slope * sideways), g.grasp_z if aligned else g.clear_z)
                return Plan(np.array([*grasp_point[:2], max(floor, min(p[2], g.hover))]), aligned_yaw, GRIP_OPEN)
            closing = np.linalg.norm(p - grasp_point) <= g.close_tol
            return Plan(grasp_point, aligned_yaw, GRIP_CLOSED if closing else GRIP_OPEN)

        return grasp

    def _finger_yaw(self, hand: float, yaw: float, left: float, wrist: float) -> float:
        """The hand's angle for the grasp: along the peg's axis (the pads on its long faces), the nearer of its two
        alignments whose turn afterwards (``left``) the last joint can make (it turns against the hand)."""
        options = sorted((hand + wrap(yaw - hand) + k * np.pi for k in (-1, 0, 1)), key=lambda h: abs(h - hand))
        for option in options:
            if abs(wrist - (option - hand) - left) <= WRIST_LIMIT:
                return float(option)
        raise RuntimeError(f"no grasp of the peg at {np.degrees(yaw):.0f} degrees lets the wrist (at "
                           f"{np.degrees(wrist):.0f}) turn {np.degrees(left):.0f} degrees")

    # ------------------------------------------------------------ pushing
    def _push_plan(self, tcp: np.ndarray, centre: np.ndarray, yaw: float, left: float,
                   qpos: np.ndarray) -> Callable[[np.ndarray, float], Plan | None]:
        """Push one end of the peg sideways (fingers closed) for the turn ``left``, getting behind it first."""
        g = self.gains
        pos = tcp[:3]
        axis = np.array([np.cos(yaw), np.sin(yaw)])
        side = np.array([-axis[1], axis[0]])  # pushing the +axis end along +side turns the peg counter-clockwise
        touch = -(PEG_HALF_WIDTH + g.finger)  # how far across (along the push) the fingers touch the peg's face

        def engaged(p: np.ndarray, end: float, normal: np.ndarray) -> bool:
            rel = p[:2] - centre[:2]
            return bool(p[2] < g.push_z + 0.02 and g.lever - 0.05 < rel @ (end * axis) < PEG_HALF_LENGTH + 0.005
                        and touch - g.standoff - 0.02 < rel @ normal < -PEG_HALF_WIDTH)

        options = []
        for end in (1.0, -1.0):
            normal = end * np.sign(left) * side
            behind = centre[:2] + end * g.lever * axis + normal * (touch - g.standoff)
            finish = behind + normal * (g.standoff + abs(left) / g.turn_per_metre)  # where the fingers would end
            cost = 0.0 if engaged(pos, end, normal) else float(np.linalg.norm(behind - pos[:2])) + 0.1
            cost += g.home_weight * float(np.linalg.norm(finish - np.asarray(g.home)))
            cost += g.reach_weight * sum(max(low - x, 0.0, x - high) for x, (low, high) in
                                         zip((*behind, *finish), (*g.start_reach, *g.finish_reach)))
            options.append((cost, end, normal, behind))
        _, end, normal, behind = min(options, key=lambda option: option[0])
        pushing = engaged(pos, end, normal)  # within the chunk: from the step the fingers come down behind it

        def push(p: np.ndarray, h: float) -> Plan | None:
            nonlocal pushing
            sideways = float(np.linalg.norm(behind - p[:2]))
            pushing = pushing or (sideways <= g.over_tol and p[2] <= g.push_z + 0.01)
            if pushing:  # the peg turns as the fingers go on past its face
                still = abs(left) - g.turn_per_metre * max(float((p[:2] - centre[:2]) @ normal) - touch, 0.0)
                if still <= g.done:
                    return None
                speed = float(np.clip(g.push_fraction * still / g.turn_per_metre, *g.push_speed))
                return Plan(np.array([*(p[:2] + normal * speed / g.approach_gain), g.push_z]), None, GRIP_CLOSED)
            funnel = g.push_z + min(g.hover - g.push_z, g.push_funnel * sideways)  # come down only once behind it
            if p[2] < funnel - 0.02 and sideways > 2 * g.over_tol:  # low beside the peg: up first, then across
                return Plan(np.array([p[0], p[1], funnel]), None, GRIP_CLOSED)
            return Plan(np.array([*behind, funnel]), None, GRIP_CLOSED)

        return push

    # ------------------------------------------------------------ motion
    def _chunk(self, tcp_pose: np.ndarray, step: np.ndarray,
               plan: Callable[[np.ndarray, float], Plan | None]) -> np.ndarray:
        """Actions that steer the predicted TCP to each step's planned point and the hand to its planned angle
        (pointing down), braking for the TCP's coasting; where the plan is done, zero motion (hold still)."""
        g = self.gains
        pos = tcp_pose[:3].copy()
        rot = Rotation.from_quat(tcp_pose[[4, 5, 6, 3]])  # ManiSkill poses are (x, y, z, qw, qx, qy, qz)
        chunk = np.zeros((self.spec.chunk_len, self.spec.action_dim))
        chunk[:, -1] = GRIP_CLOSED
        for k in range(self.spec.chunk_len):
            target = plan(pos, hand_yaw(rot))
            if target is None:
                break  # the rest of the chunk holds still, fingers closed
            want = g.approach_gain * (target.point - pos)
            want *= min(1.0, g.max_step / max(np.abs(want).max(), 1e-9))
            a_pos = np.clip((want - COAST_GAIN * step) / (DRIVE_GAIN * POS_SCALE), -1.0, 1.0)
            yaw = hand_yaw(rot) if target.yaw is None else target.yaw
            turn = float(np.clip(wrap(yaw - hand_yaw(rot), 2 * np.pi), -g.max_turn, g.max_turn))
            aim = Rotation.from_rotvec([0.0, 0.0, hand_yaw(rot) + turn]) * R_DOWN  # pointing down, turned
            dr = (aim * rot.inv()).as_rotvec()
            a_rot = dr / (TURN_GAIN * ROT_SCALE)
            a_rot /= max(1.0, float(np.linalg.norm(a_rot)))
            chunk[k] = [*a_pos, *a_rot, target.grip]
            step = DRIVE_GAIN * POS_SCALE * a_pos + COAST_GAIN * step
            pos = pos + step
            rot = Rotation.from_rotvec(a_rot * TURN_GAIN * ROT_SCALE) * rot
        return chunk


__all__ = ["GRIP_CLOSED", "GRIP_OPEN", "PegTurnController", "Plan", "STRATEGIES", "TurnGains", "hand_yaw",
           "remaining_turn", "wrap"]
