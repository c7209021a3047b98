"""MIKASA-Robo-VLA's Rotate tasks as sb3-memret tasks: the peg's start angle must be remembered.

RotateLenientPos-VLA-v0 and RotateLenientPosNeg-VLA-v0 (60 control steps), RotateStrictPos-VLA-v0 and
RotateStrictPosNeg-VLA-v0 (90). The env is MIKASA's own (``mikasa-robo-suite``), with its protocol:
``pd_ee_delta_pose``, 128x128 cameras, the ``normalized_dense`` reward, success counted once per episode,
evaluation at seeds 4242424242 + i. MIKASA's wrapper table gives Rotate no ``CurriculumPhaseNoopActionWrapper``:
actions act from the first step.

**Episode:** a blue peg (24 x 5 x 5 cm, both halves the same blue) lies on the table. The instruction, MIKASA's,
names a new angle every episode, ``rotate the peg by 38 degrees to match the target angle.`` (Strict adds ``while
keeping the center of the peg in place``), and the angle counts from where the peg lay at the start: once the peg
has turned, where it started is known only to a memory of the first frame.

**Randomisations** (MIKASA's): the peg's start angle about the vertical (uniform over 360 degrees), its centre
(x and y uniform within 10 cm of the table's centre), the rotation (Pos: 0.1 rad to 90 degrees, counter-clockwise
seen from above; PosNeg: 0.1 rad to 45 degrees either way, the sign by a coin), the arm's initial joints.

**Success:** MIKASA's, at any step: the peg's angle minus its start angle (both about the vertical, wrapped to
+-180 degrees) is within 0.1 rad (5.7 degrees) of the rotation, and the arm is static (every joint slower than
0.2 rad/s); Strict also needs the peg's centre within 5 cm of its start in x and in y.

**Facts:** one, read from the base camera's first frame: the peg's top face (its one shade, (58, 102, 187), whatever
the peg's angle) is cast onto the plane of that face (z = 5 cm) through the camera's shipped calibration
(``core.calibration``) and its long axis is the principal axis of those points (``peg_on_table``): ``the peg started
at 35 degrees.``, the angle of the axis from the table's x axis, counter-clockwise, in whole degrees from 0 to 179
(the halves look alike, so a camera cannot tell 35 from 215 degrees; nor need it: the rotation counts from the peg as
it lay). Measured at the development seeds 5000-5099 (``lab/2026-11-27-rotate-reader-error/rotate_reader_error.py``):
the reading is off the simulator's angle by 0.25 degrees on average, 0.67 at the 95th percentile, 1.32 at most
(rounding to whole degrees adds up to 0.5, and MIKASA's instruction rounds the rotation to whole degrees, up to 0.5
more): well inside MIKASA's 5.7. Decoys are worded alike about other things (``the key started at 57 degrees.``). The
controller sees ``RotateObservation`` only (never ``oracle_info`` or ``task_cue``), so the start reaches it only
through its prompt, and the rotation only through the instruction.

**The instruction** is MIKASA's ``info["language_instruction"]`` of the episode's reset, lowercased into the prompt
contract's form (``angle_deg`` holds a signed whole number: ``sb3_memret.controllers.prompts``); the task reads it there
(``instruction_in_info``), never from ``task_cue``.

**The expert** (``PegTurnController``, ``turn_expert``) pushes the peg round on Lenient (60 steps) and turns it in
hand on Strict (90 steps, the centre kept in place); without a fact it takes the peg to have started at 0 degrees.
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.observation import STATE_KEY
from sb3_memret.memory.schema import MemoryType
from sb3_memret.controllers.prompts import NUMBER, SIGNED_NUMBER, PromptTemplate
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.perception import DetectorObservation
from sb3_memret.tasks.mikasa.rotate.expert import PegTurnController

# MIKASA's LANGUAGE_INSTRUCTION_TEMPLATEs in the prompt contract's form (lowercase; ``angle_deg`` is MIKASA's field).
LENIENT_INSTRUCTION = "rotate the peg by {angle_deg} degrees to match the target angle."
STRICT_INSTRUCTION = ("rotate the peg by {angle_deg} degrees to match the target angle while keeping the center of "
                      "the peg in place.")
FACT_TEMPLATE = "the {entity} started at {start_deg} degrees."
CUE_ENTITY = "peg"
CUE_RELATION = "started_at"  # OTHER's template, "the {entity} {relation} {value}.", reads FACT_TEMPLATE
CUE_FACT = "the peg started at {start_deg} degrees."
FIELDS = (("angle_deg", SIGNED_NUMBER), ("start_deg", NUMBER))  # a signed rotation, and a start angle in [0, 360)
ANGLES: tuple[str, ...] = tuple(f"{d} degrees" for d in range(180))  # a fact's values: the start, 0-179 degrees

# env id -> (the instruction template, the control steps of an episode, how the expert turns the peg)
ROTATE_TASKS: dict[str, tuple[str, int, str]] = {
    "RotateLenientPos-VLA-v0": (LENIENT_INSTRUCTION, 60, "push"),
    "RotateLenientPosNeg-VLA-v0": (LENIENT_INSTRUCTION, 60, "push"),
    "RotateStrictPos-VLA-v0": (STRICT_INSTRUCTION, 90, "grasp"),
    "RotateStrictPosNeg-VLA-v0": (STRICT_INSTRUCTION, 90, "grasp"),
}
DEFAULT_START_DEG = 0  # where the expert takes the peg to have started without a fact: a guess
WRONG_OFFSET_DEG = 90  # a wrong fact's start: the peg then ends 90 degrees off, 16 times MIKASA's tolerance
GROUP_DEG = 30  # episodes are reported by their start angle in bins this wide

PEG_TOP_RGB = (58, 102, 187)  # how the peg's top face renders on the base camera (measured; flat-shaded, one shade)
PEG_TOP_TOLERANCE = 8  # per channel: the peg's sides render (37-41, 65-73, 119-133), the table and robot far off
PEG_TOP_Z = 0.05  # MIKASA's peg lies on the table, 2 * PEG_HALF_WIDTH high
MIN_PEG_PIXELS = 20  # its top face covers 90-130 pixels at 128x128


def peg_top_mask(rgb: np.ndarray) -> np.ndarray:
    """The pixels of the peg's top face in one frame (H, W, 3)."""
    rgb = np.asarray(rgb).astype(np.int16)
    return np.all(np.abs(rgb - np.asarray(PEG_TOP_RGB, dtype=np.int16)) <= PEG_TOP_TOLERANCE, axis=-1)


def peg_on_table(rgb: np.ndarray, intrinsic: np.ndarray, extrinsic: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Where the peg lies in one base-camera frame (H, W, 3): its top face's centre (x, y) and its long axis's angle
    (degrees in [0, 180), from the table's x axis, counter-clockwise), or None if it is out of sight. Each top-face
    pixel is cast along its camera ray (OpenCV ``intrinsic`` 3x3, world-to-camera ``extrinsic`` 3x4) onto the plane
    of the face; the axis is the principal axis of those points."""
    rows, cols = np.nonzero(peg_top_mask(rgb))
    if len(rows) < MIN_PEG_PIXELS:
        return None
    rotation, translation = np.asarray(extrinsic)[:, :3], np.asarray(extrinsic)[:, 3]
    pixels = np.stack([cols + 0.5, rows + 0.5, np.ones(len(rows))])
    rays = rotation.T @ (np.linalg.inv(np.asarray(intrinsic)) @ pixels)
    origin = -rotation.T @ translation
    points = (origin[:, None] + (PEG_TOP_Z - origin[2]) / rays[2] * rays)[:2].T
    centre = points.mean(axis=0)
    _, vectors = np.linalg.eigh(np.cov((points - centre).T))
    axis = vectors[:, -1]
    return centre, float(np.degrees(np.arctan2(axis[1], axis[0])) % 180.0)


def start_value(angle_deg: float) -> str:
    """A start angle as a fact's value: whole degrees in 0-179 (``35 degrees``)."""
    return ANGLES[int(round(angle_deg)) % 180]


def peg_yaw(quaternion: Any) -> Any:
    """The angle (radians in [0, pi)) of the long axis of pegs lying flat, from their (B, 4) wxyz quaternions, in
    the array type given (torch or numpy): the axis's direction, its two ends alike."""
    w, x, y, z = (quaternion[..., i] for i in range(4))
    if hasattr(quaternion, "detach"):
        import torch

        return torch.remainder(torch.atan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z)), np.pi)
    return np.remainder(np.arctan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z)), np.pi)


class StartWriter:
    """Writes ``the peg started at {angle} degrees.`` from the reset frame's sighting of the peg (``seen_start_deg``,
    what the base camera showed); later frames change nothing (the peg turns, its start does not)."""

    relations = {"start": (MemoryType.OTHER, CUE_RELATION)}

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        seen = frame.state.get("seen_start_deg") if frame.steps == 0 else None
        return [] if seen is None else [(0, {("start", CUE_ENTITY): start_value(seen)})]


class RotateObservation(DetectorObservation):
    """A Rotate observation cut to a controller's view: the joints, the hand, the cameras, and the peg as a detector
    reports it: its centre (``extra/peg_positions`` (B, 1, 3), ``extra/peg_visible`` (B, 1)) and the angle of its
    long axis (``extra/peg_yaw`` (B,), radians in [0, pi): its halves look alike, so a detector cannot tell its ends
    apart). Not its start, nor the rotation (``oracle_info``, ``task_cue``)."""

    def __init__(self, env: gym.Env):
        super().__init__(env, lambda base: [base.peg], "peg")
        batch = int(getattr(env.unwrapped, "num_envs", 1))
        self.observation_space["extra"]["peg_yaw"] = spaces.Box(0.0, np.pi, (batch,), np.float32)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        yaw = peg_yaw(self.env.unwrapped.peg.pose.q)
        like = obs["extra"]["tcp_pose"]
        out["extra"]["peg_yaw"] = yaw.to(like.device).clone() if hasattr(like, "detach") else as_numpy(yaw)
        return out


class RotateTask(MikasaCueTask):
    """MIKASA-Robo-VLA's Rotate tasks: turn the peg by the instruction's angle from where it started."""

    field, detector_key = "start_deg", "peg"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, CUE_RELATION, CUE_FACT
    vocabulary = ANGLES
    observation_wrapper: ClassVar = RotateObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives Rotate none
    perceives_every_step = False  # the start is read from the reset frame alone: the camera renders at decisions
    instruction_in_info = True

    def __init__(self, env_id: str = "RotateLenientPos-VLA-v0"):
        if env_id not in ROTATE_TASKS:
            raise ValueError(f"unknown Rotate task {env_id!r}; expected one of {sorted(ROTATE_TASKS)}")
        super().__init__(env_id, len(ANGLES))
        self.instruction_text, self.max_control_steps, self.strategy = ROTATE_TASKS[env_id]
        self.template = PromptTemplate(instructions=(self.instruction_text,), fact_templates=(FACT_TEMPLATE,), fields=FIELDS)

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs = to_numpy(obs)
        base = env.unwrapped
        starts = np.degrees(as_numpy(base.initial_rotations).reshape(-1))  # privileged: for metrics only
        success = as_numpy(info["success"]).reshape(-1)
        seen: list[float | None] = [None] * len(success)
        instructions: list[str | None] = [None] * len(success)
        if reset:  # what the base camera saw of the peg before anything moved, and the episode's instruction
            rgb = obs["sensor_data"]["base_camera"]["rgb"]
            pegs = [peg_on_table(rgb[i], BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC) for i in range(len(success))]
            seen = [None if peg is None else peg[1] for peg in pegs]
            instructions = [episode_instruction(info, i) for i in range(len(success))]
        return [EnvFrame(select_obs(obs, i), {"start_deg": float(starts[i] % 180.0), "seen_start_deg": seen[i],
                                              "instruction": instructions[i]}, None, bool(success[i]))
                for i in range(len(success))]

    def writer(self, source: str = "seeded") -> StartWriter:
        return StartWriter()

    def episode(self, frame: EnvFrame) -> Episode:
        """The true fact is the one the writer writes (the camera's reading, a degree or so off the simulator's: the
        memory the controller needs); without a sighting, the simulator's angle (no fact is written then, so no
        retrieval can be right). The group is the simulator's start angle in ``GROUP_DEG`` bins."""
        start, seen = frame.state["start_deg"], frame.state["seen_start_deg"]
        if frame.state["instruction"] is None:
            raise ValueError("an episode starts at a reset frame (frames(..., reset=True)): it carries the instruction")
        value = start_value(start if seen is None else seen)
        low = int(start // GROUP_DEG) * GROUP_DEG
        return Episode(self.cue_entity, f"{low} to {low + GROUP_DEG - 1} degrees", ((self.cue_key, value),),
                       {"start_deg": start, "instruction": frame.state["instruction"]})

    def instruction(self, episode: Episode) -> str:
        return episode.details["instruction"]

    def oracle_facts(self, episode: Episode) -> list[str]:
        return [self.cue_fact.format(start_deg=start_value(episode.details["start_deg"]).split()[0])]

    def wrong_facts(self, episode: Episode) -> list[str]:
        """The start turned by ``WRONG_OFFSET_DEG``: the expert then turns the peg to 90 degrees off its goal."""
        wrong = start_value(episode.details["start_deg"] + WRONG_OFFSET_DEG)
        return [self.cue_fact.format(start_deg=wrong.split()[0])]

    def expert(self) -> PegTurnController:
        return PegTurnController(self.template, self.strategy, DEFAULT_START_DEG)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        features = demo_layout.demo_features(("centre",), with_images, key="peg")
        state = features[STATE_KEY]
        names = [*state["names"], "peg_yaw"]
        return {**features, STATE_KEY: {**state, "shape": (len(names),), "names": names}}

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.append_state(demo_layout.demo_frame(obs, with_images, key="peg"), obs["extra"]["peg_yaw"])


def episode_instruction(info: Mapping[str, Any], i: int) -> str:
    """Env ``i``'s instruction as MIKASA's env states it at a reset (``info["language_instruction"]``), lowercased into
    the prompt contract's form; a ValueError where the info has none."""
    if "language_instruction" not in info:
        raise ValueError("the reset's info has no 'language_instruction': Rotate's instruction names each episode's "
                         f"angle, which MIKASA's env states there; info holds {sorted(info)}")
    stated = info["language_instruction"]
    return str(stated if isinstance(stated, str) else stated[i]).lower()


__all__ = ["ANGLES", "CUE_FACT", "DEFAULT_START_DEG", "FACT_TEMPLATE", "LENIENT_INSTRUCTION", "ROTATE_TASKS",
           "RotateObservation", "RotateTask", "STRICT_INSTRUCTION", "StartWriter", "episode_instruction",
           "peg_on_table", "peg_top_mask", "peg_yaw", "start_value"]
