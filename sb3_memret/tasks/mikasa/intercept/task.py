"""MIKASA-Robo-VLA's Intercept and InterceptGrab (Slow, Medium, Fast; ``-VLA-v0``) as sb3-memret tasks: the rolling
ball's motion, seen over several frames, must be remembered to catch it.

The env is MIKASA's own (``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``, 128x128 cameras, the
``normalized_dense`` reward, success counted once per episode, evaluation at seeds 4242424242 + i. MIKASA's wrapper
table gives these tasks no ``CurriculumPhaseNoopActionWrapper``: actions act from the first step.

**Episode:** a red ball (2 cm radius) is launched across the table toward the robot's left (+y), from near the
base camera's left edge (often beyond it); InterceptGrab must grasp it and hold the arm still, Intercept must get it
onto a red-and-white target (10 cm radius) 20 cm beyond the ball's line (MIKASA's instruction says deflect; its
success asks only that the ball get there, and this task's expert carries it). Episodes last 60 control steps.

**Randomisations** (MIKASA's): the ball's start, x = -0.2 +- 0.15 m and y = -0.9 to -0.65 m (uniform; Intercept
drops it from 4 cm, InterceptGrab sets it on the table); its launch velocity, y uniform in the task's range (Slow
0.25-0.5, Medium 0.5-0.75, Fast 0.75-1.0 m/s) and x uniform in 0-0.05 m/s; Intercept's target, x 20 cm beyond the
ball's start, y uniform in -0.2 to 0.2 m; the arm's initial joints. The ball slides, then rolls at 5/7 of its
launch speed (a solid sphere's rolling; measured 0.713-0.715) from about the third step, losing < 0.3 % a step.

**Success:** MIKASA's, at any step (MIKASA's harness counts it from the steps, never the reset: InterceptGrab's
reset info reads the previous episode's finger contacts, so ``frames`` reports no success at a reset). Intercept:
the ball's centre (xy) within the target's 10 cm radius. InterceptGrab: the robot grasps the ball (``is_grasping``)
and the arm is static (every arm joint < 0.2 rad/s).

**The memory:** one frame shows where the ball is, never where it is going or how fast: its speed (18-36, 36-54 or
54-71 cm/s rolling, by task) is only in the difference between frames. The writer reads it from the base camera: at
every control step the ball's pixels (saturated red; the target's red is pinker) are cast onto the table plane
through the camera's shipped calibration (``core.calibration``; ``ball_on_table``); from the third step on (rolling)
a line fitted to ``MIN_SIGHTINGS`` sightings spanning ``MIN_SPAN`` steps gives the speed, written once as ``the ball
rolls left at 37 cm/s.`` (cm/s: the prompt contract has no decimals), at steps 7-17 (a slow ball comes into view
late). Decoys are worded alike about other things at any variant's speed (``the key rolls left at 30 cm/s.``). The
controller sees ``InterceptObservation`` only: its joints, its hand, where the ball is while it is in the base
camera's view (as a detector would report it: not while the ball is beyond the image's edge) and where the target is;
never ``oracle_info`` (MIKASA's launch velocity), so the ball's velocity reaches it only through its prompt.

Who needs the memory is the controller's strategy: the expert (``InterceptController``) meets the ball on the move,
pacing it at the prompt's speed while it comes down around it, and replans every 4 steps from where it sees the
ball. A speed too high by more than ~7 cm/s makes it overtake the ball (a fingertip lands on it); one too low lets
the ball roll into the leading finger, which still catches it. Without a fact it assumes 45 cm/s, the middle of all
three variants' speeds (they share one instruction): it then misses nearly every Slow ball and catches most Medium
and Fast ones. A controller that blocked the ball's path and grasped it at rest might not need the speed at all
(not tried here).

Truth, for metrics only: the rolling speed, 5/7 of ``oracle_info``'s y; a written fact is the true one when it is
about the ball, names the right direction and a speed within ``SPEED_TOLERANCE`` (the reader's measured error is
at most 3 cm/s); the oracle fact states the truth to the cm/s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from scipy import ndimage

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.controllers.prompts import NUMBER, PromptTemplate
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC, BASE_CAMERA_SIZE
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT
from sb3_memret.tasks.mikasa.intercept.expert import DIRECTIONS, InterceptController, Motion
from sb3_memret.tasks.mikasa.core.perception import DetectorObservation, stack_positions

# MIKASA's LANGUAGE_INSTRUCTIONs in the prompt contract's form (lowercase; they parse as they are).
INTERCEPT_INSTRUCTION = "intercept the rolling ball by moving to its path and deflecting it toward the target."
GRAB_INSTRUCTION = "intercept the rolling ball and grasp it to stop it."
FACT_TEMPLATE = "the {entity} rolls {direction} at {speed} cm/s."
CUE_ENTITY = "ball"
CUE_RELATION = "rolls"  # OTHER's template, "the {entity} {relation} {value}.", with the value "left at 37 cm/s"
CUE_FACT = "the ball rolls {direction} at {speed} cm/s."
FIELDS = (("speed", NUMBER),)  # a speed is a whole number of cm/s


@dataclass(frozen=True)
class InterceptVariant:
    """One of MIKASA's six ids: its launch speeds (m/s, MIKASA's ``VELOCITY_RANGE``) and what success asks."""

    launch: tuple[float, float]
    carry: bool  # Intercept: bring the ball onto the target; InterceptGrab: grasp it and hold still

    @property
    def instruction(self) -> str:
        return INTERCEPT_INSTRUCTION if self.carry else GRAB_INSTRUCTION

    @property
    def rolling(self) -> tuple[float, float]:
        """The rolling speeds (m/s) the launch speeds give."""
        return (ROLLING * self.launch[0], ROLLING * self.launch[1])


ROLLING = 5 / 7  # a launched ball slides, then rolls at 5/7 of its launch speed (a solid sphere; measured)
SPEEDS = {"Slow": (0.25, 0.5), "Medium": (0.5, 0.75), "Fast": (0.75, 1.0)}
VARIANTS: dict[str, InterceptVariant] = {
    f"{family}{pace}-VLA-v0": InterceptVariant(launch, carry)
    for family, carry in (("Intercept", True), ("InterceptGrab", False)) for pace, launch in SPEEDS.items()}
ROLLING_SPEEDS = (ROLLING * SPEEDS["Slow"][0], ROLLING * SPEEDS["Fast"][1])  # every variant's, m/s: 0.18-0.71
EPISODE_STEPS = 60
SPEED_TOLERANCE = 5  # cm/s: a written speed this close to the truth is the true fact (metrics only); the reader's
# error was at most 3 cm/s (mean -0.3 to -0.8) over 120 development episodes (lab/2026-11-27-intercept-probe/intercept_probe.py)

BALL_CENTRE_Z = 0.02  # the rolling ball's centre: its radius
ROLLING_FROM = 3  # the first control step at which the ball rolls (it slides, or drops, before)
MIN_SIGHTINGS = 5  # rolling sightings the speed is fitted to ...
MIN_SPAN = 4  # ... spanning this many control steps (0.2 s)
MIN_BALL_PIXELS = 3  # the ball covers 10-13 pixels at 128x128 where it is first seen


def ball_mask(rgb: np.ndarray) -> np.ndarray:
    """The ball's pixels: saturated red (it renders as about (180, 4, 4)); the target's red and white rings
    (about (130, 45, 48)), the wood and the robot never pass."""
    rgb = np.asarray(rgb).astype(np.int16)
    return (rgb[..., 0] >= 100) & (rgb[..., 1] <= 25) & (rgb[..., 2] <= 25)


def ball_on_table(rgb: np.ndarray, intrinsic: np.ndarray, extrinsic: np.ndarray,
                  plane_z: float = BALL_CENTRE_Z) -> np.ndarray | None:
    """Where the ball is on the table, (x, y), from one frame (H, W, 3), or None when it is not seen whole: the
    one red blob's mean pixel, cast along the camera ray (OpenCV ``intrinsic`` 3x3, world-to-camera ``extrinsic``
    3x4) onto the plane ``z = plane_z``. A blob cut by the image's edge is not read (its mean is off-centre)."""
    labels, n_blobs = ndimage.label(ball_mask(rgb), structure=np.ones((3, 3)))
    sizes = np.bincount(labels.ravel(), minlength=n_blobs + 1)[1:]
    blobs = [i + 1 for i, size in enumerate(sizes) if size >= MIN_BALL_PIXELS]
    if len(blobs) != 1:
        return None
    pixels = np.argwhere(labels == blobs[0])
    height, width = np.asarray(rgb).shape[:2]
    if pixels.min() == 0 or pixels[:, 0].max() == height - 1 or pixels[:, 1].max() == width - 1:
        return None
    row, col = pixels.mean(axis=0) + 0.5
    rotation, translation = np.asarray(extrinsic)[:, :3], np.asarray(extrinsic)[:, 3]
    ray = rotation.T @ (np.linalg.inv(np.asarray(intrinsic)) @ np.array([col, row, 1.0]))
    origin = -rotation.T @ translation
    if abs(ray[2]) < 1e-9:
        return None
    return (origin + (plane_z - origin[2]) / ray[2] * ray)[:2]


def fit_speed(sightings: list[tuple[int, float, float]]) -> Motion:
    """The motion a line through (control step, x, y) sightings gives: its y slope's sign and size."""
    steps, _, ys = (np.asarray(column, dtype=np.float64) for column in zip(*sightings))
    slope = np.polyfit(steps * CONTROL_DT, ys, 1)[0]
    return Motion("left" if slope >= 0 else "right", abs(float(slope)))


def motion_value(motion: Motion) -> str:
    """The fact's value for a motion: ``left at 37 cm/s``."""
    return f"{motion.direction} at {round(motion.speed * 100)} cm/s"


def motion_fact(motion: Motion, entity: str = CUE_ENTITY) -> str:
    return FACT_TEMPLATE.format(entity=entity, direction=motion.direction, speed=round(motion.speed * 100))


def parse_value(value: str) -> Motion | None:
    """The motion a fact's value states (``left at 37 cm/s``), or None for another value."""
    words = value.split()
    if len(words) != 4 or words[0] not in DIRECTIONS or words[1::2] != ["at", "cm/s"] or not words[2].isdigit():
        return None
    return Motion(words[0], int(words[2]) / 100.0)


class MotionWriter:
    """Writes ``the ball rolls left at 37 cm/s.`` once, at the control step its sightings first suffice:
    ``MIN_SIGHTINGS`` rolling sightings (from step ``ROLLING_FROM``) spanning ``MIN_SPAN`` steps. The reset frame
    (``steps == 0``) starts an episode; percepts are the ball's table points, None where it was not seen."""

    relations = {"motion": (MemoryType.OTHER, CUE_RELATION)}

    def __init__(self) -> None:
        self.t = 0  # control steps of the episode before the frame being read
        self.sightings: list[tuple[int, float, float]] = []
        self.written = False

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self.t, self.sightings, self.written = 0, [], False
        out = []
        for offset, seen in frame.timed_percepts():
            step = self.t + offset
            if seen is None or step < ROLLING_FROM or self.written:
                continue
            self.sightings.append((step, float(seen[0]), float(seen[1])))
            if len(self.sightings) >= MIN_SIGHTINGS and step - self.sightings[0][0] >= MIN_SPAN:
                self.written = True
                out.append((offset, {("motion", CUE_ENTITY): motion_value(fit_speed(self.sightings))}))
        self.t += frame.steps
        return out


@dataclass(frozen=True)
class MotionEpisode(Episode):
    """An episode whose true fact is a measured speed: a fact about the ball with the true direction and a speed
    within ``tolerance`` cm/s of the truth is the true one (``true_facts`` holds the truth to the cm/s)."""

    tolerance: int = SPEED_TOLERANCE

    def is_true(self, entry: MemoryEntry) -> bool:
        (key, value), = self.true_facts
        stated, truth = parse_value(entry.value), parse_value(value)
        return (entry.key == key and stated is not None and stated.direction == truth.direction
                and abs(stated.speed - truth.speed) * 100 <= self.tolerance)


def _in_view(points: Any) -> np.ndarray:
    """Whether each point (B, 3) projects inside the base camera's image, in front of it (its shipped calibration)."""
    points = as_numpy(points).astype(np.float64)
    camera = points @ BASE_CAMERA_EXTRINSIC[:, :3].T + BASE_CAMERA_EXTRINSIC[:, 3]
    pixel = camera @ BASE_CAMERA_INTRINSIC.T
    depth = camera[:, 2]
    u, v = pixel[:, 0] / np.where(depth > 0, depth, 1.0), pixel[:, 1] / np.where(depth > 0, depth, 1.0)
    return (depth > 0) & (u >= 0) & (u <= BASE_CAMERA_SIZE) & (v >= 0) & (v <= BASE_CAMERA_SIZE)


class InterceptObservation(DetectorObservation):
    """An Intercept observation cut to a controller's view: the joints, the hand, the cameras, the ball as a
    detector reports it (``extra/ball_positions`` (B, 1, 3), ``extra/ball_visible`` (B, 1): while its centre is in
    the base camera's image; zeros otherwise), and for Intercept the target's centre (``extra/goal_position``,
    (B, 3): always in view). The ball's velocity is not among them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, lambda base: [base.ball], "ball")
        base = env.unwrapped
        self.with_goal = hasattr(base, "goal_region")
        if self.with_goal:
            batch = int(getattr(base, "num_envs", 1))
            self.observation_space["extra"]["goal_position"] = spaces.Box(-np.inf, np.inf, (batch, 3), np.float32)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        base = self.env.unwrapped
        like = out["extra"]["ball_positions"]
        seen = _in_view(like[:, 0])
        if hasattr(like, "detach"):
            import torch

            seen = torch.as_tensor(seen, device=like.device)
        out["extra"]["ball_visible"] = seen[:, None]
        out["extra"]["ball_positions"] = like * seen[:, None, None]
        if self.with_goal:
            out["extra"]["goal_position"] = stack_positions([base.goal_region.pose.p], like=obs["extra"]["tcp_pose"])[:, 0]
        return out


class InterceptTask(MikasaCueTask):
    """MIKASA-Robo-VLA's Intercept{Slow,Medium,Fast}-VLA-v0 (catch the ball, bring it onto the target) and
    InterceptGrab{Slow,Medium,Fast}-VLA-v0 (catch it and hold still)."""

    field, detector_key = "speed", "ball"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, CUE_RELATION, CUE_FACT
    vocabulary = tuple(DIRECTIONS)
    observation_wrapper: ClassVar = InterceptObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives these tasks none
    perceives_every_step = True  # the speed is read from several frames
    max_control_steps = EPISODE_STEPS

    def __init__(self, env_id: str = "InterceptMedium-VLA-v0"):
        if env_id not in VARIANTS:
            raise ValueError(f"unknown Intercept task {env_id!r}; expected one of {sorted(VARIANTS)}")
        super().__init__(env_id, len(DIRECTIONS))
        self.variant = VARIANTS[env_id]
        self.instruction_text = self.variant.instruction
        self.template = PromptTemplate(instructions=(self.instruction_text,), fact_templates=(FACT_TEMPLATE,), fields=FIELDS)

    @property
    def default_speed(self) -> float:
        """The expert's guess without a fact (m/s): the middle of every variant's rolling speeds, as MIKASA's Slow,
        Medium and Fast share one instruction (a controller cannot tell them apart by its prompt)."""
        return float(np.mean(ROLLING_SPEEDS))

    # ------------------------------------------------------------ simulation
    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs = to_numpy(obs)
        launch = as_numpy(env.unwrapped.oracle_info).reshape(-1, 3)  # privileged: for metrics only
        success = as_numpy(info["success"]).reshape(-1)
        if reset:  # MIKASA's harness counts success from steps only: InterceptGrab's reset info reads the finger
            success = np.zeros_like(success)  # contacts of the previous episode (a held ball reads as grasped)
        return [EnvFrame(select_obs(obs, i), {"motion": Motion("left" if launch[i, 1] >= 0 else "right",
                                                               ROLLING * abs(float(launch[i, 1])))},
                         None, bool(success[i]))
                for i in range(len(success))]

    def perceive(self, env: gym.Env, obs: Any) -> tuple[float, float] | None:
        seen = ball_on_table(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0], BASE_CAMERA_INTRINSIC,
                             BASE_CAMERA_EXTRINSIC)
        return None if seen is None else (float(seen[0]), float(seen[1]))

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> MotionWriter:
        return MotionWriter()

    def episode(self, frame: EnvFrame) -> MotionEpisode:
        motion = frame.state["motion"]
        cm = round(motion.speed * 100)
        band = 5 * (cm // 5)
        return MotionEpisode(self.cue_entity, f"{motion.direction} {band}-{band + 5} cm/s",
                             ((self.cue_key, motion_value(motion)),), {"ball_speed_cm_s": cm})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` facts worded as the ball's about other things (``the key rolls left at 30
        cm/s.``), each at a speed drawn from every variant's (18-71 cm/s): a decoy drawn from this variant's own
        speeds would tell the expert the speed band, and it catches most balls on any speed in the band, so recall
        would succeed without the ball's fact. The ball's own fact comes only from what the camera saw."""
        low, high = ROLLING_SPEEDS
        vocab = sorted(set(seeding.vocabulary))
        return [MemoryEntry.create(MemoryType.OTHER, str(word), self.cue_relation,
                                   motion_value(Motion("left", float(rng.uniform(low, high)))), 0)
                for word in rng.choice(vocab, size=seeding.location_decoys, replace=False)]

    # ------------------------------------------------------------ prompts and controllers
    def oracle_facts(self, episode: Episode) -> list[str]:
        (_, value), = episode.true_facts
        return [motion_fact(parse_value(value))]

    def wrong_facts(self, episode: Episode) -> list[str]:
        """The ball's fact at the far end of every variant's speeds from the true one (18 or 71 cm/s: 27 cm/s or
        more off), in the true direction."""
        (_, value), = episode.true_facts
        truth = parse_value(value)
        low, high = ROLLING_SPEEDS
        far = high if truth.speed < (low + high) / 2 else low
        return [motion_fact(Motion(truth.direction, far))]

    def expert(self) -> InterceptController:
        """The catch expert; without a fact it assumes the middle of the task's speeds, a guess."""
        return InterceptController(self.template, self.default_speed, carry=self.variant.carry)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        features = demo_layout.demo_features(("red",), with_images, key="ball")  # ball_red_x, ..., ball_red_visible
        return demo_layout.with_state_extra(features, "goal") if self.variant.carry else features

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        frame = demo_layout.demo_frame(obs, with_images, key="ball")
        return demo_layout.append_state(frame, obs["extra"]["goal_position"]) if self.variant.carry else frame


__all__ = ["CUE_FACT", "EPISODE_STEPS", "FACT_TEMPLATE", "GRAB_INSTRUCTION", "INTERCEPT_INSTRUCTION",
           "InterceptObservation", "InterceptTask", "InterceptVariant", "MotionEpisode", "MotionWriter", "ROLLING",
           "SPEED_TOLERANCE", "VARIANTS", "ball_mask", "ball_on_table", "fit_speed", "motion_fact", "motion_value",
           "parse_value"]
