"""A scripted frozen controller for MIKASA's RememberColor tasks: touch the cube the prompt names.

It stands in for a VLA finetuned on RememberColor with the cue written into its prompt: the colour
comes only from the prompt's fact (``the cue cube was red.``). With no fact, or a colour word it
does not know, it touches its ``default`` colour, a fixed guess (as the drawer's controller opens the
top drawer when its prompt names none), so without memory it succeeds at chance; with no default it
holds still (zero actions). It reads only what ``ControllerObservation`` gives
(joints, hand pose, the colour detector's cube positions), never the simulator, and keeps no state
between calls: every ``act`` re-reads the observation and the prompt.

Motion: with its gripper half open, the TCP steers down a funnel onto the named cube (the lowest
it may go rises with the horizontal distance, so it arrives from above, fingers either side of the
cube, clear of the others), stops 1-2 cm above the cube's centre and holds still, which makes the
robot static as MIKASA's success needs. While the named cube is out of sight (cue and delay
phases, where MIKASA zeroes actions anyway) it heads for a ready pose above the cubes, so the
steps of a chunk that fall after the cubes appear are not wasted.

Within a chunk, motion is predicted with a model of ManiSkill 3.0.1's ``pd_ee_delta_pose`` arm fitted
on this task (40 episodes of random actions): the TCP moves ``0.243 * delta + 0.378 * v * dt`` per
control step, ``delta`` the commanded translation (action * 0.1 m) and ``v`` the TCP's velocity at
the step's start (read from ``qvel`` through the arm's Jacobian); that is 39 mm per step at a full
action and 17 mm of coasting after it. Knowing the coasting, the chunk brakes in time.
"""

from __future__ import annotations

import contextlib
import functools
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from sb3_memret.controllers.base import ControllerSpec, FrozenController, Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate, build_prompt
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES

# MIKASA's LANGUAGE_INSTRUCTION in the prompt contract's form (lowercase; it parses as is).
INSTRUCTION = "observe the cube's color, wait, then touch the cube of the same color."
# Like a finetuned VLA it follows the colour word whatever the fact is about, so a decoy ("the key was
# blue.") misleads it as the wrong cue would: retrieval has to pick the cue's fact.
FACT_TEMPLATE = "the {entity} was {colour}."
CUE_FACT = "the cue cube was {colour}."
PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(FACT_TEMPLATE,))

# ManiSkill 3.0.1 pd_ee_delta_pose (as in tasks/drawer/expert.py): translation = action * 0.1 m,
# rotation = action * -0.1 rad, both in the base frame (world-aligned here: the base is at x = -0.615).
POS_SCALE = 0.1
ROT_SCALE = -0.1
CONTROL_DT = 0.05  # 20 Hz control
DRIVE_GAIN = 0.243  # TCP step per commanded translation (fitted)
COAST_GAIN = 0.378  # TCP step per (velocity * CONTROL_DT) at the step's start (fitted)
TURN_GAIN = 0.39  # the rotation's share per step (tasks/drawer/expert.py's PLANT_GAIN)
R_DOWN = Rotation.from_matrix(np.diag([1.0, -1.0, -1.0]))  # the reset pose: pointing down, fingers along y


def colour_prompt(colour: str | None) -> str:
    """The controller's prompt: the instruction, plus the cue fact when ``colour`` is given."""
    facts = [] if colour is None else [CUE_FACT.format(colour=colour)]
    return build_prompt(INSTRUCTION, facts, PROMPT_TEMPLATE)


def named_word(parsed: ParsedPrompt, field: str = "colour") -> str | None:
    """The ``field`` word (``colour``, ``shape``) of the prompt's first fact that has one, or None."""
    return next((v for f in parsed.facts for k, v in f.fields if k == field), None)


@functools.lru_cache(maxsize=1)
def _panda_chain() -> Any:
    """The Panda arm's kinematic chain to its TCP, from ManiSkill's URDF (for the TCP's velocity)."""
    import mani_skill
    import pytorch_kinematics as pk
    import torch

    urdf = Path(mani_skill.__file__).parent / "assets/robots/panda/panda_v3.urdf"
    with contextlib.redirect_stderr(io.StringIO()):  # its parser lists 28 joint attributes it does not know
        chain = pk.build_serial_chain_from_urdf(urdf.read_bytes(), "panda_hand_tcp")
    return chain.to(dtype=torch.float64)


def tcp_velocity(qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """Linear TCP velocities (B, 3) in the robot's base frame from arm joint positions and velocities."""
    import torch

    q = torch.as_tensor(np.asarray(qpos)[:, :7], dtype=torch.float64)
    jac = _panda_chain().jacobian(q)[:, :3].numpy()
    return np.einsum("bij,bj->bi", jac, np.asarray(qvel, dtype=np.float64)[:, :7])


@dataclass(frozen=True)
class TouchGains:
    """Speeds (m or rad per control step) and the geometry of the touch."""

    max_step: float = 0.039  # per axis: a full action's steady-state step
    approach_gain: float = 0.7  # plan a step of this fraction of the remaining distance
    arrive_tol: float = 0.008  # this close to the touch point it only brakes: no creeping that unsettles the arm
    turn_speed: float = 0.05
    touch_height: float = 0.01  # TCP above the cube centre at the touch: fingertips (9 mm lower) straddle it
    hover_height: float = 0.07  # the funnel's top: TCP height above the touch point when far sideways
    funnel_slope: float = 1.2  # the lowest the TCP may be above the touch point, per metre sideways
    grip: float = 0.6  # gripper command: fingers 3 cm either side of the TCP, 1 cm clear of a 4 cm cube
    ready: tuple[float, float, float] = (-0.08, 0.0, 0.10)  # where to wait while the named cube is out of sight
    # the farthest x (world) a step may command the TCP to: pd_ee_delta_pose solves IK for the TCP's pose plus the
    # commanded delta, and a target beyond the arm's reach fails to solve, so the arm stops short instead
    max_x: float = np.inf


class ScriptedTouchController(FrozenController):
    """Moves the TCP onto the object whose word (by default its colour) the prompt's fact names, then
    holds still. ``vocabulary[i]`` names candidate i of the detector (``extra/{key}_positions``,
    ``extra/{key}_visible``) and ``field`` is the fact's field that names it; RememberShape's expert
    is this controller with shapes. ``default``: the word it acts on when the prompt names none it knows
    (None: it holds still). With ``wait_for_all`` it heads for the named object only once every candidate
    is in sight (the choice), and waits at its ready pose before: a cue shown alone is not touched where
    no wrapper freezes the arm (MIKASA's -Long tasks)."""

    stateful = False

    def __init__(self, chunk_len: int = 8, gains: TouchGains | None = None,
                 vocabulary: Sequence[str] = COLOUR_NAMES, field: str = "colour",
                 prompt_template: PromptTemplate = PROMPT_TEMPLATE, key: str = "cube", default: str | None = None,
                 wait_for_all: bool = False):
        if default is not None and default not in vocabulary:
            raise ValueError(f"default {field} {default!r} is not one of {list(vocabulary)}")
        self.gains = gains or TouchGains()
        self.vocabulary, self.field, self.key, self.default = tuple(vocabulary), field, key, default
        self.wait_for_all = wait_for_all
        self.spec = ControllerSpec(
            action_convention="pd_ee_delta_pose", chunk_len=chunk_len, action_dim=7, prompt_template=prompt_template
        )
        self._batch = 0

    def reset(self, seeds: Sequence[int]) -> None:
        self._batch = len(seeds)

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        self._check_env_ids(env_ids, seeds, self._batch)

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        words = self._chosen(parsed)
        if all(w is None for w in words):
            return chunks
        extra = obs["extra"]
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        targets = as_numpy(extra[f"{self.key}_positions"]).astype(np.float64)
        visible = as_numpy(extra[f"{self.key}_visible"]).astype(bool)
        velocity = tcp_velocity(as_numpy(obs["agent"]["qpos"]), as_numpy(obs["agent"]["qvel"]))
        for i, word in enumerate(words):
            if word is None:
                continue  # no cue fact (or a word it was never trained on) and no default: hold still
            index = self.vocabulary.index(word)
            choosing = not self.wait_for_all or bool(visible[i].all())
            target = targets[i, index] if index < visible.shape[1] and visible[i, index] and choosing else None
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, target)
        return chunks

    def _chosen(self, parsed: Sequence[ParsedPrompt]) -> list[str | None]:
        """The word of the object each prompt sends it to: its fact's, else ``default`` (None: hold still)."""
        named = [named_word(p, self.field) for p in parsed]
        return [w if w in self.vocabulary else self.default for w in named]

    def _waypoint(self, pos: np.ndarray, cube: np.ndarray | None) -> np.ndarray:
        """Where to head next: the touch point, but never below the funnel over the cube (nor back up it)."""
        g = self.gains
        if cube is None:
            return np.asarray(g.ready, dtype=np.float64)
        touch = cube[2] + g.touch_height
        floor = touch + min(g.hover_height, g.funnel_slope * float(np.linalg.norm(cube[:2] - pos[:2])))
        return np.array([cube[0], cube[1], max(touch, min(pos[2], floor))])

    def _grip(self, pos: np.ndarray, goal: Any) -> float:
        """The gripper command at a step whose TCP is predicted at ``pos`` (touching: half open throughout)."""
        return self.gains.grip

    def _chunk(self, tcp_pose: np.ndarray, step: np.ndarray, goal: Any) -> np.ndarray:
        """Actions that steer the predicted TCP to the waypoints, braking for its coasting, then hold it there."""
        g = self.gains
        pos = tcp_pose[:3].copy()
        rot = Rotation.from_quat(tcp_pose[[4, 5, 6, 3]])  # ManiSkill poses are (x, y, z, qw, qx, qy, qz)
        chunk = np.zeros((self.spec.chunk_len, self.spec.action_dim))
        for k in range(self.spec.chunk_len):
            error = self._waypoint(pos, goal) - pos
            moving = bool(np.linalg.norm(error) > g.arrive_tol)
            want = g.approach_gain * error if moving else np.zeros(3)
            want *= min(1.0, g.max_step / max(np.abs(want).max(), 1e-9))
            a_pos = np.clip((want - COAST_GAIN * step) / (DRIVE_GAIN * POS_SCALE), -1.0, 1.0)
            a_pos[0] = min(a_pos[0], max(0.0, (g.max_x - pos[0]) / POS_SCALE))
            dr = (R_DOWN * rot.inv()).as_rotvec() if moving else np.zeros(3)  # arrived: no turning either
            dr *= min(1.0, g.turn_speed / max(np.linalg.norm(dr), 1e-9))
            a_rot = dr / (TURN_GAIN * ROT_SCALE)
            a_rot /= max(1.0, np.linalg.norm(a_rot))
            chunk[k] = [*a_pos, *a_rot, self._grip(pos, goal)]
            step = DRIVE_GAIN * POS_SCALE * a_pos + COAST_GAIN * step
            pos = pos + step
            rot = Rotation.from_rotvec(a_rot * TURN_GAIN * ROT_SCALE) * rot
        return chunk


__all__ = ["CUE_FACT", "FACT_TEMPLATE", "INSTRUCTION", "PROMPT_TEMPLATE", "ScriptedTouchController", "TouchGains",
           "colour_prompt", "named_word", "tcp_velocity"]
