"""A scripted frozen controller for MIKASA's Intercept and InterceptGrab: catch the rolling ball in the gripper,
then hold it still (InterceptGrab) or carry it onto the target (Intercept).

It stands in for a VLA finetuned on these tasks with the ball's motion written into its prompt (``the ball
rolls left at 37 cm/s.``). It reads only what ``InterceptObservation`` gives (joints, hand pose, where the ball
is while the base camera has it in view, where the target is), never the simulator, and keeps no state: every
``act`` re-reads the observation and the prompt. One observation shows where the ball is, not where it is going:
the velocity comes only from the prompt's first fact that names a speed, whatever the fact is about (a decoy,
``the key rolls left at 30 cm/s.``, misleads it as a wrong fact would). With none it assumes ``default_speed``
to the left (MIKASA launches every ball toward the robot's left): a guess (the tasks give the middle of all their
speeds).

Plan, each call, with the ball predicted along its line at the prompt's velocity: while the ball is out of view,
wait above where it comes in; once seen, fly with the gripper open (fingers either side of the ball's line, one
ahead of it, one behind) to where the ball will be, matching its velocity, above its top; once over it, come down
around it while keeping pace, and close the fingers on it at its centre's height. A speed too high by more than
~7 cm/s overtakes the ball during the descent and a fingertip lands on it; one too low lets the ball roll into the
leading finger, which still catches it (up to ~20 cm/s too low; a far slower pace leaves it behind). No single frame
holds the speed. Holding it (fingers closed on a 4 cm gap, the TCP at
the ball): InterceptGrab brakes and holds still (MIKASA's success: grasped and the arm static); Intercept carries
it onto the target (MIKASA's success: the ball's centre within the target's 10 cm radius).

Motion within a chunk uses ``ScriptedTouchController``'s fitted model of the ``pd_ee_delta_pose`` arm: the TCP
moves ``0.243 * delta + 0.378 * v * dt`` per control step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from sb3_memret.controllers.base import ControllerSpec, FrozenController, Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.touch_expert import (
    CONTROL_DT,
    COAST_GAIN,
    DRIVE_GAIN,
    POS_SCALE,
    R_DOWN,
    ROT_SCALE,
    TURN_GAIN,
    tcp_velocity,
)

GRIP_OPEN, GRIP_CLOSED = 1.0, -1.0
DIRECTIONS = {"left": 1.0, "right": -1.0}  # the sign of the ball's y velocity: the robot faces +x, its left is +y


class Motion(NamedTuple):
    """A ball's motion as a prompt states it: ``direction`` (left, right) and ``speed`` (m/s)."""

    direction: str
    speed: float

    @property
    def velocity(self) -> np.ndarray:
        """The ball's velocity on the table (x, y), m/s."""
        return np.array([0.0, DIRECTIONS[self.direction] * self.speed])


def stated_motion(parsed: ParsedPrompt) -> Motion | None:
    """The motion of the prompt's first fact that names a speed (cm/s) and a direction, or None."""
    for fact in parsed.facts:
        fields = dict(fact.fields)
        if "speed" in fields and fields.get("direction") in DIRECTIONS:
            return Motion(fields["direction"], int(fields["speed"]) / 100.0)
    return None


@dataclass(frozen=True)
class CatchGains:
    """The catch and the carry (metres, per control step where a rate).

    ``catch_grip``: MIKASA's harness builds the Panda with its wrist camera (``panda_wristcam``, ManiSkill's v3
    model). Its fingers driven fully shut (-1: each to 1 cm past closed) on a ball caught up to 1.2 cm off its centre
    squeezed it out: 6 of 100 InterceptSlow oracle episodes at seeds 5000-5099 failed so. Driven to 5 mm each (-0.4),
    they hold it (all 6, and every episode of every variant at seeds 5000-5059)."""

    max_step: float = 0.039  # per axis: a full action's steady-state step
    track_gain: float = 0.4  # each step makes up this share of the gap to the ball (beyond keeping its pace)
    approach_gain: float = 0.7  # the same for a fixed point (waiting, carrying, holding)
    turn_speed: float = 0.05  # rad per step toward pointing down, fingers across the ball's line
    hover_height: float = 0.065  # TCP height while closing in: fingertips (9 mm below it) clear the ball's top
    catch_height: float = 0.02  # TCP height at the catch: the fingertips at the ball's centre
    over_x: float = 0.008  # come down once the TCP is predicted over the ball this closely (across its line) ...
    over_y: float = 0.012  # ... and along it (open fingers leave 2 cm either way)
    committed_height: float = 0.045  # below this, go on down
    close_height: float = 0.03  # close the fingers below this height with the ball between them:
    close_x: float = 0.012  # this close across the line ...
    close_y: float = 0.02  # ... and along it
    catch_grip: float = -0.4  # the gripper's command closing on the ball: fingers driven to 5 mm, not shut (see below)
    held_gap: tuple[float, float] = (0.03, 0.05)  # the fingers' gap when closed on the 4 cm ball ...
    held_reach: float = 0.03  # ... with the ball's centre this close to the TCP: the ball is in hand
    carry_height: float = 0.04  # the TCP's height while carrying the ball to the target
    ready: tuple[float, float, float] = (-0.2, -0.3, 0.12)  # where to wait while the ball is out of view


class InterceptController(FrozenController):
    """Catches the ball at the velocity its prompt states; ``carry`` (Intercept) then takes it onto the target
    (``extra/goal_position``), otherwise (InterceptGrab) holds it still. ``default_speed`` (m/s): the guess
    without a fact."""

    stateful = False

    def __init__(self, prompt_template: PromptTemplate, default_speed: float, carry: bool, chunk_len: int = 8,
                 gains: CatchGains | None = None):
        if not default_speed > 0:
            raise ValueError(f"default_speed must be a positive speed in m/s, got {default_speed}")
        self.default = Motion("left", float(default_speed))
        self.carry, self.gains = carry, gains or CatchGains()
        self.spec = ControllerSpec(action_convention="pd_ee_delta_pose", chunk_len=chunk_len, action_dim=7,
                                   prompt_template=prompt_template)
        self._batch = 0

    def reset(self, seeds: Sequence[int]) -> None:
        self._batch = len(seeds)

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        self._check_env_ids(env_ids, seeds, self._batch)

    def motion_of(self, parsed: ParsedPrompt) -> Motion:
        """The motion the prompt states, or the default guess without one."""
        return stated_motion(parsed) or self.default

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        extra = obs["extra"]
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        ball = as_numpy(extra["ball_positions"]).astype(np.float64)[:, 0]
        seen = as_numpy(extra["ball_visible"]).astype(bool)[:, 0]
        goal = as_numpy(extra["goal_position"]).astype(np.float64) if self.carry else None
        qpos = as_numpy(obs["agent"]["qpos"]).astype(np.float64)
        steps = tcp_velocity(qpos, as_numpy(obs["agent"]["qvel"])) * CONTROL_DT
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        g = self.gains
        for i, p in enumerate(parsed):
            pos = tcp[i, :3]
            held = (g.held_gap[0] <= qpos[i, 7:9].sum() <= g.held_gap[1] and seen[i]
                    and np.linalg.norm(ball[i] - pos) <= g.held_reach)
            if held:
                point = np.array([goal[i, 0], goal[i, 1], g.carry_height]) if self.carry else pos
                chunks[i] = self._hold(tcp[i], steps[i], point)
            elif seen[i]:
                chunks[i] = self._catch(tcp[i], steps[i], ball[i], self.motion_of(p).velocity)
            else:
                chunks[i] = self._hold(tcp[i], steps[i], np.asarray(g.ready), grip=GRIP_OPEN)
        return chunks

    # ------------------------------------------------------------ chunks
    def _catch(self, tcp_pose: np.ndarray, step: np.ndarray, ball: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """Actions that keep pace with the ball predicted along ``velocity`` (m/s), come down over it and close."""
        g = self.gains
        pos, rot = tcp_pose[:3].copy(), _rotation(tcp_pose)
        pace = np.array([*velocity * CONTROL_DT, 0.0])  # the ball's step
        ball = np.array([ball[0], ball[1], 0.0])
        chunk = np.zeros((self.spec.chunk_len, self.spec.action_dim))
        closing = False
        for k in range(self.spec.chunk_len):
            gap = ball - pos
            over = abs(gap[0]) < g.over_x and abs(gap[1]) < g.over_y
            height = g.catch_height if over or pos[2] < g.committed_height else g.hover_height
            closing |= pos[2] < g.close_height and abs(gap[0]) < g.close_x and abs(gap[1]) < g.close_y
            want = pace + g.track_gain * np.array([gap[0], gap[1], height - pos[2]])
            chunk[k], step, pos, rot = self._step(pos, step, rot, want, g.catch_grip if closing else GRIP_OPEN)
            ball = ball + pace
        return chunk

    def _hold(self, tcp_pose: np.ndarray, step: np.ndarray, point: np.ndarray, grip: float = GRIP_CLOSED) -> np.ndarray:
        """Actions that take the TCP to ``point`` and hold it there (braking for the arm's coasting)."""
        pos, rot = tcp_pose[:3].copy(), _rotation(tcp_pose)
        chunk = np.zeros((self.spec.chunk_len, self.spec.action_dim))
        for k in range(self.spec.chunk_len):
            chunk[k], step, pos, rot = self._step(pos, step, rot, self.gains.approach_gain * (point - pos), grip)
        return chunk

    def _step(self, pos: np.ndarray, step: np.ndarray, rot: Rotation, want: np.ndarray,
              grip: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, Rotation]:
        """One action toward a TCP step of ``want`` (capped), turning toward pointing down; and the predicted step,
        position and orientation after it."""
        g = self.gains
        want = want * min(1.0, g.max_step / max(np.abs(want).max(), 1e-9))
        a_pos = np.clip((want - COAST_GAIN * step) / (DRIVE_GAIN * POS_SCALE), -1.0, 1.0)
        turn = (R_DOWN * rot.inv()).as_rotvec()
        turn *= min(1.0, g.turn_speed / max(np.linalg.norm(turn), 1e-9))
        a_rot = turn / (TURN_GAIN * ROT_SCALE)
        a_rot /= max(1.0, np.linalg.norm(a_rot))
        step = DRIVE_GAIN * POS_SCALE * a_pos + COAST_GAIN * step
        rot = Rotation.from_rotvec(a_rot * TURN_GAIN * ROT_SCALE) * rot
        return np.array([*a_pos, *a_rot, grip]), step, pos + step, rot


def _rotation(tcp_pose: np.ndarray) -> Rotation:
    return Rotation.from_quat(tcp_pose[[4, 5, 6, 3]])  # ManiSkill poses are (x, y, z, qw, qx, qy, qz)


__all__ = ["CatchGains", "DIRECTIONS", "GRIP_CLOSED", "GRIP_OPEN", "InterceptController", "Motion", "stated_motion"]
