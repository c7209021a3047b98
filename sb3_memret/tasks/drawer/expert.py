"""A scripted frozen controller for DrawerCubeTakeOut-v1 that acts on what its prompt says.

It stands in for a finetuned VLA on a CPU: it reads the target drawer only from the prompt
(``the cube is in drawer layer 2.``; like the finetuned π0.5 it follows the layer number,
not the object word), opens the top drawer when no layer is given, and sees the object its
instruction names (``pick out the {entity}.``, any object) only once that object's drawer is
open, through the task's camera-like ``target_detection``. It never reads the simulator. At every ``act`` call it re-reads the state and the prompt, so a prompt that
changes mid-episode changes what it does (it lets go, closes the wrong drawer, and goes to
the new one).

Each env's progress is a small state machine whose transitions are checked on the observed
state at every call; within a chunk, motion is predicted with a first-order model of the
``pd_ee_delta_pose`` arm (measured: the TCP moves ~0.39 of the commanded delta per step).
Its phases follow what is seen, not only what it did, so it also labels the states another
policy leads it into (DAgger): a hand already on the insertion line goes on in, a handle already
gripped is pulled, an object already between the fingers is lifted, one dropped is grasped
again, a drawer pushed back in is opened again before it reaches in.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from sb3_memret.controllers.base import ControllerSpec, FrozenController, Obs, as_numpy
from sb3_memret.tasks.drawer.cabinet import LAYERS, CabinetLayout
from sb3_memret.tasks.drawer.prompts import ANY_OBJECT, check_prompt_layer
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate

# ManiSkill 3.0.1 pd_ee_delta_pose: translation = action * 0.1 m in the base frame; rotation =
# action * rot_lower (-0.1 rad) as a base-frame rotation, i.e. +1 turns by -0.1 rad.
POS_SCALE = 0.1
ROT_SCALE = -0.1
PLANT_GAIN = 0.39
OPEN, CLOSE = 1.0, -1.0
HOLD_RADIUS = 0.03  # m from the TCP within which an object's centre is between the fingers
HOLD_WIDTH = (0.015, 0.07)  # finger opening (m) of a closed grasp on one of the task's objects (squeezed: < 3 cm)

R_DOWN = Rotation.from_matrix(np.diag([1.0, -1.0, -1.0]))  # approach -z, fingers along y
# Handles are grasped from the front, pitched 35 deg down: a level hand would need the
# Panda's wrist (joint 6) past its limit this close to the base.
R_HANDLE = Rotation.from_euler("y", np.deg2rad(-35.0)) * R_DOWN
HANDLE_APPROACH = R_HANDLE.apply([0.0, 0.0, 1.0])
HANDLE_REACH = 0.10  # m in front of a handle, along HANDLE_APPROACH, where the straight insertion starts
HANDLE_GRIP_REACH = 0.025  # m from the handle's bar within which closed fingers hold it (a shallow grasp pulls too)


class Phase(enum.Enum):
    REACH_HANDLE = "reach_handle"
    INSERT = "insert"
    GRIP_HANDLE = "grip_handle"
    PULL = "pull"
    RELEASE = "release"
    BACK_OFF = "back_off"
    PUSH_APPROACH = "push_approach"
    PUSH = "push"
    RISE = "rise"
    ABOVE_CUBE = "above_cube"
    DESCEND = "descend"
    GRIP_CUBE = "grip_cube"
    LIFT = "lift"
    IDLE = "idle"


HANDLE_PHASES = (Phase.REACH_HANDLE, Phase.INSERT)  # on the way to a handle, nothing gripped yet
CUBE_PHASES = (Phase.RISE, Phase.ABOVE_CUBE, Phase.DESCEND)  # on the way to the cube, nothing grasped yet


@dataclass
class Perception:
    """What one env's observation says, as the controller reads it."""

    tcp_pos: np.ndarray
    tcp_rot: Rotation
    finger_width: float
    opening: np.ndarray
    target_visible: bool
    target_pos: np.ndarray
    target_yaw: float

    @classmethod
    def from_obs(cls, obs: Obs, i: int) -> "Perception":
        eef = as_numpy(obs["agent"]["eef_state"])[i]
        det = as_numpy(obs["extra"]["target_detection"])[i]
        target_rot = Rotation.from_quat(det[[5, 6, 7, 4]]) if det[0] > 0.5 else Rotation.identity()
        x_axis = target_rot.as_matrix()[:, 0]
        yaw = (np.arctan2(x_axis[1], x_axis[0]) + np.pi / 4) % (np.pi / 2) - np.pi / 4
        return cls(
            tcp_pos=eef[:3].astype(np.float64),
            tcp_rot=Rotation.from_rotvec(eef[3:6]),
            finger_width=float(eef[6] + eef[7]),
            opening=as_numpy(obs["extra"]["drawer_opening"])[i].astype(np.float64),
            target_visible=bool(det[0] > 0.5),
            target_pos=det[1:4].astype(np.float64),
            target_yaw=float(yaw),
        )


@dataclass
class _Plan:
    """One env's progress: the phase, the drawer it is about, how many calls it has lasted."""

    phase: Phase = Phase.REACH_HANDLE
    layer: int = 1
    drawer: int = 1
    calls: int = 0


@dataclass(frozen=True)
class ScriptedGains:
    """Speeds (m or rad per control step) and tolerances of the scripted motions."""

    free_speed: float = 0.012
    fine_speed: float = 0.006
    pull_speed: float = 0.005
    turn_speed: float = 0.05
    reach_tol: float = 0.015
    fine_tol: float = 0.008
    turn_tol: float = 0.08
    open_target: float = 0.27
    reach_in_clearance: float = 0.07  # the cube's centre this far in front of the handle above it, or re-open first
    phase_timeout_calls: int = 20


class ScriptedDrawerController(FrozenController):
    """Opens the drawer its prompt names, takes the cube out if it sees one there."""

    def __init__(
        self,
        layout: CabinetLayout | None = None,
        chunk_len: int = 32,
        gains: ScriptedGains | None = None,
        prompt_template: PromptTemplate | None = None,
    ):
        self.layout = layout or CabinetLayout()
        self.gains = gains or ScriptedGains()
        self.spec = ControllerSpec(
            action_convention="pd_ee_delta_pose",
            chunk_len=chunk_len,
            prompt_template=prompt_template or ANY_OBJECT,
        )
        self._plans: list[_Plan] = []

    def reset(self, seeds: Sequence[int]) -> None:
        self._plans = [_Plan() for _ in seeds]

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        self._check_env_ids(env_ids, seeds, len(self._plans))
        for i in env_ids:
            self._plans[i] = _Plan()

    def phases(self) -> list[Phase]:
        """The current phase of every env (for introspection and tests)."""
        return [p.phase for p in self._plans]

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(self._plans) != len(prompts):
            raise RuntimeError(f"reset() was called for {len(self._plans)} envs but act() got {len(prompts)} prompts")
        chunks = []
        for i, (plan, prompt) in enumerate(zip(self._plans, parsed)):
            layer = check_prompt_layer(prompt) or LAYERS[0]
            seen = Perception.from_obs(obs, i)
            if layer != plan.layer:
                self._retarget(plan, layer)
            self._advance(plan, seen)
            chunks.append(self._chunk(plan, seen))
        return np.stack(chunks)

    # ------------------------------------------------------------ transitions
    def _retarget(self, plan: _Plan, layer: int) -> None:
        plan.layer = layer
        if plan.phase in (Phase.REACH_HANDLE, Phase.INSERT):
            self._enter(plan, Phase.REACH_HANDLE, drawer=layer)
        elif plan.phase in (Phase.GRIP_HANDLE, Phase.PULL, Phase.IDLE):
            self._enter(plan, Phase.RELEASE)

    def _advance(self, plan: _Plan, s: Perception) -> None:
        """Move through every phase whose goal the observed state already meets."""
        for _ in range(len(Phase)):
            nxt = self._transition(plan, s)
            if nxt is None:
                break
            self._enter(plan, *nxt)
        plan.calls += 1
        if plan.calls > self.gains.phase_timeout_calls and plan.phase not in (Phase.LIFT, Phase.IDLE):
            self._enter(plan, Phase.RELEASE)  # stuck: let go and re-decide

    def _transition(self, plan: _Plan, s: Perception) -> tuple[Phase, int] | tuple[Phase] | None:
        g, d, p = self.gains, plan.drawer, plan.phase
        handle = self.layout.handle_center(d, s.opening[d - 1])
        if p in HANDLE_PHASES and (s.opening[d - 1] >= g.open_target - 0.02 or
                                   d == plan.layer and self._reachable(plan, s)):
            return (Phase.RELEASE,)  # open enough (another policy may have opened it): go for the cube
        if p in HANDLE_PHASES and self._gripping_handle(s, handle):
            return (Phase.PULL,)  # another policy went in and closed the fingers on it already
        if p is Phase.REACH_HANDLE and self._in_handle_corridor(s, handle):
            return (Phase.INSERT,)
        if p is Phase.INSERT and not self._in_handle_corridor(s, handle):
            return (Phase.REACH_HANDLE,)  # pushed off the line: start the insertion again
        if p is Phase.INSERT and self._at(s, handle, R_HANDLE, g.fine_tol):
            return (Phase.GRIP_HANDLE,)
        if p is Phase.GRIP_HANDLE and plan.calls > 0:
            return (Phase.PULL,) if s.finger_width > 0.006 else (Phase.RELEASE,)
        if p is Phase.PULL:
            if s.opening[d - 1] >= g.open_target - 0.015 or not self._on_handle(s, handle, 0.04):
                return (Phase.RELEASE,)
        if p is Phase.RELEASE and s.finger_width > 0.07:
            return (Phase.BACK_OFF,)
        if p is Phase.BACK_OFF and (s.tcp_pos[0] < handle[0] - 0.07 or np.linalg.norm(s.tcp_pos - handle) > 0.12):
            return self._after_back_off(plan, s)
        if p is Phase.PUSH_APPROACH and self._at(s, handle - 0.05 * HANDLE_APPROACH, R_HANDLE, g.reach_tol):
            return (Phase.PUSH,)
        if p is Phase.PUSH and s.opening[d - 1] < 0.02:
            return (Phase.BACK_OFF,)
        if p in CUBE_PHASES and self._holding(s):
            return (Phase.LIFT,)  # it is in hand already (another policy grasped it)
        if p in CUBE_PHASES and not self._reachable(plan, s):
            return (Phase.RELEASE,)  # the drawer was pushed in or the cube lost from view: back off, re-decide
        if p is Phase.RISE and s.tcp_pos[2] > self._rise_height(d) - 0.02:
            return (Phase.ABOVE_CUBE,) if s.target_visible else (Phase.IDLE,)
        if p is Phase.ABOVE_CUBE and self._at(s, s.target_pos + [0, 0, 0.12], self._down(s), g.fine_tol + 0.004):
            return (Phase.DESCEND,)
        if p is Phase.DESCEND and self._at(s, s.target_pos, self._down(s), g.fine_tol):
            return (Phase.GRIP_CUBE,)
        if p is Phase.GRIP_CUBE and plan.calls > 0:
            return (Phase.LIFT,) if s.finger_width > 0.03 else (Phase.RELEASE,)
        if p is Phase.LIFT and not self._holding(s):
            return (Phase.RELEASE,)  # dropped it
        if p is Phase.IDLE and (self._reachable(plan, s) or s.opening[plan.layer - 1] < g.open_target - 0.02):
            return (Phase.RELEASE,)  # the cube came into view or the named drawer was pushed in: re-decide
        return None

    def _after_back_off(self, plan: _Plan, s: Perception) -> tuple[Phase, int] | tuple[Phase]:
        """Decide what to do once the hand is clear of the drawers."""
        g = self.gains
        if self._reachable(plan, s):
            return (Phase.RISE, plan.drawer)
        stray = [layer for layer in LAYERS if layer != plan.layer and s.opening[layer - 1] > 0.03]
        if stray:
            return (Phase.PUSH_APPROACH, stray[0])
        if s.opening[plan.layer - 1] < g.open_target - 0.02:
            return (Phase.REACH_HANDLE, plan.layer)
        return (Phase.IDLE,)  # the named drawer is open and holds no cube

    def _in_handle_corridor(self, s: Perception, handle: np.ndarray) -> bool:
        """The hand is on the line it inserts along (from ``HANDLE_REACH`` in front of the handle to the handle),
        turned for the grasp: from there the insertion goes on, wherever the hand came from."""
        offset = s.tcp_pos - handle
        along = -float(offset @ HANDLE_APPROACH)
        lateral = float(np.linalg.norm(offset + along * HANDLE_APPROACH))
        return -self.gains.fine_tol <= along <= HANDLE_REACH + self.gains.reach_tol and lateral < self.gains.reach_tol \
            and (R_HANDLE * s.tcp_rot.inv()).magnitude() < self.gains.turn_tol

    def _on_handle(self, s: Perception, handle: np.ndarray, reach: float) -> bool:
        """The hand is within ``reach`` of the handle's vertical bar, at any height along it."""
        offset = s.tcp_pos - handle
        return bool(np.linalg.norm(offset[:2]) < reach and abs(offset[2]) < self.layout.handle_half_size[2] + reach)

    def _gripping_handle(self, s: Perception, handle: np.ndarray) -> bool:
        """The fingers are closed on the handle's bar."""
        return self._on_handle(s, handle, HANDLE_GRIP_REACH) and 0.006 < s.finger_width < 0.05

    def _reachable(self, plan: _Plan, s: Perception) -> bool:
        """The cube is in view and a hand coming from above can reach it: in the top drawer, or far enough in front
        of the handle of the drawer above (a drawer pushed half in, or a cube pushed deep, puts it under that
        handle, where the hand jams)."""
        if not s.target_visible:
            return False
        if plan.layer == LAYERS[0]:
            return True
        handle_above = self.layout.handle_center(plan.layer - 1, 0.0)
        return bool(s.target_pos[0] < handle_above[0] - self.gains.reach_in_clearance)

    @staticmethod
    def _holding(s: Perception) -> bool:
        """The target is between closed fingers."""
        return s.target_visible and np.linalg.norm(s.target_pos - s.tcp_pos) < HOLD_RADIUS \
            and HOLD_WIDTH[0] < s.finger_width < HOLD_WIDTH[1]

    @staticmethod
    def _enter(plan: _Plan, phase: Phase, drawer: int | None = None) -> None:
        plan.phase = phase
        plan.calls = 0
        if drawer is not None:
            plan.drawer = drawer

    # ------------------------------------------------------------------ goals
    def _goal(self, plan: _Plan, s: Perception) -> tuple[np.ndarray, Rotation, float, float]:
        """(position, orientation, gripper, speed) the current phase steers to."""
        g, d, p = self.gains, plan.drawer, plan.phase
        handle = self.layout.handle_center(d, s.opening[d - 1])
        if p is Phase.REACH_HANDLE:
            return handle - HANDLE_REACH * HANDLE_APPROACH, R_HANDLE, OPEN, g.free_speed
        if p is Phase.INSERT:
            return handle, R_HANDLE, OPEN, g.fine_speed
        if p is Phase.GRIP_HANDLE:
            return handle, R_HANDLE, CLOSE, g.fine_speed
        if p is Phase.PULL:
            return self.layout.handle_center(d, g.open_target + 0.01), R_HANDLE, CLOSE, g.pull_speed
        if p is Phase.RELEASE:
            return s.tcp_pos, s.tcp_rot, OPEN, g.fine_speed
        if p is Phase.BACK_OFF:
            return s.tcp_pos - 0.09 * HANDLE_APPROACH, s.tcp_rot, OPEN, g.fine_speed
        if p is Phase.PUSH_APPROACH:
            return handle - 0.05 * HANDLE_APPROACH, R_HANDLE, CLOSE, g.free_speed
        if p is Phase.PUSH:
            return self.layout.handle_center(d, 0.0) - [0.025, 0, 0], R_HANDLE, CLOSE, g.fine_speed
        if p is Phase.RISE:
            return np.array([s.tcp_pos[0], 0.0, self._rise_height(d)]), self._down(s), OPEN, g.free_speed
        if p is Phase.ABOVE_CUBE:
            return s.target_pos + [0, 0, 0.12], self._down(s), OPEN, g.free_speed
        if p is Phase.DESCEND:
            return s.target_pos, self._down(s), OPEN, g.fine_speed
        if p is Phase.GRIP_CUBE:
            return s.tcp_pos, s.tcp_rot, CLOSE, g.fine_speed
        if p is Phase.LIFT:
            lift = np.array([s.tcp_pos[0] - 0.05, s.tcp_pos[1], self._rise_height(d) + 0.05])
            return lift, s.tcp_rot, CLOSE, g.fine_speed
        return s.tcp_pos, s.tcp_rot, OPEN, g.fine_speed  # IDLE

    def _rise_height(self, layer: int) -> float:
        """A TCP height that clears the front and handle of drawer ``layer``."""
        return self.layout.slot_bottom_z(layer) + self.layout.slot_height + 0.07

    @staticmethod
    def _down(s: Perception) -> Rotation:
        return Rotation.from_euler("z", s.target_yaw) * R_DOWN if s.target_visible else R_DOWN

    def _at(self, s: Perception, pos: np.ndarray, rot: Rotation, tol: float) -> bool:
        return bool(
            np.linalg.norm(s.tcp_pos - pos) < tol
            and (rot * s.tcp_rot.inv()).magnitude() < self.gains.turn_tol
        )

    # ----------------------------------------------------------------- chunks
    def _chunk(self, plan: _Plan, s: Perception) -> np.ndarray:
        """Actions that steer the predicted TCP to the phase goal, then hold it there."""
        goal_pos, goal_rot, grip, speed = self._goal(plan, s)
        pos, rot = s.tcp_pos.copy(), s.tcp_rot
        chunk = np.zeros((self.spec.chunk_len, self.spec.action_dim))
        for k in range(self.spec.chunk_len):
            dp = goal_pos - pos
            dp *= min(1.0, speed / max(np.linalg.norm(dp), 1e-9))
            dr = (goal_rot * rot.inv()).as_rotvec()
            dr *= min(1.0, self.gains.turn_speed / max(np.linalg.norm(dr), 1e-9))
            a_pos = np.clip(dp / (PLANT_GAIN * POS_SCALE), -1.0, 1.0)
            a_rot = dr / (PLANT_GAIN * ROT_SCALE)
            a_rot /= max(1.0, np.linalg.norm(a_rot))
            chunk[k] = [*a_pos, *a_rot, grip]
            pos = pos + dp
            rot = Rotation.from_rotvec(dr) * rot
        return chunk
