"""MIKASA-Robo-VLA's TakeItBack-VLA-v0 as an sb3-memret task: where the cube started must be remembered.

The spatial-memory task. The env is MIKASA's own (``mikasa-robo-suite``), with its protocol:
``pd_ee_delta_pose``, 128x128 cameras, the ``normalized_dense`` reward, success counted once per
episode, evaluation at seeds 4242424242 + i. MIKASA's wrapper table gives TakeItBack no
``CurriculumPhaseNoopActionWrapper``: actions act from the first step.

**Episode:** a green cube stands on the table; a red target lies about 25 cm in front of the robot.
The robot must bring the cube onto the red target; when the cube gets there the target turns purple,
and the robot must bring the cube back to where it started. The start's marker is hidden from the
cameras (MIKASA renders it for people only), so once the cube has moved, where it stood is known only
to a memory of the first frame. Episodes last 60 control steps.

**Randomisations** (MIKASA's): the start, on the robot's right, in the middle or on its left
(y = -0.1, 0 or 0.1 m, plus 0-5 cm, uniform) and 0-5 cm nearer or farther (x); the red target's
place (x 0.20-0.25 m, y within 2.5 cm of the middle); the arm's initial joints.

**Success:** MIKASA's, at any step: the cube has reached the red target (xy within 8 cm of its centre)
earlier in the episode, and its xy is now within 8 cm of its start.

**Facts:** one, read from the base camera's first frame: the green cube's pixels are cast onto the
table through the camera's shipped calibration (``core.calibration``; ``cube_on_table``) and its y names the
side, ``the cube started at the left.`` (the robot's left: +y); each side's centre is within 5.6 cm of every
start it names, inside MIKASA's 8 cm. Decoys are worded alike about other things (``the key started at the right.``).
The controller sees ``TakeItBackObservation`` only (never ``oracle_info``), so the start reaches it only
through its prompt.
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.memory.schema import MemoryType
from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.carry_expert import CarryBackController
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.perception import DetectorObservation, stack_positions

# MIKASA's LANGUAGE_INSTRUCTION in the prompt contract's form (lowercase; it parses as is).
INSTRUCTION = ("push the cube onto the red target, and when the target changes color, return the cube to its "
               "original position.")
FACT_TEMPLATE = "the {entity} started at the {side}."
CUE_ENTITY = "cube"
CUE_RELATION = "started_at_the"  # OTHER's template, "the {entity} {relation} {value}.", reads FACT_TEMPLATE
CUE_FACT = "the cube started at the {side}."
PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(FACT_TEMPLATE,))

# MIKASA's starts: y = k * 0.1 + U(0, 0.05) for k = -1, 0, 1 and x = U(-0.05, 0.05); side k names the centre
# (0, k * 0.1 + 0.025), within 5.6 cm of each of its starts. Words from the robot's view (it faces +x).
SIDES: tuple[str, ...] = ("right", "middle", "left")
SIDE_SPACING, SIDE_OFFSET = 0.1, 0.025
SIDE_CENTRES: dict[str, tuple[float, float]] = {s: (0.0, (k - 1) * SIDE_SPACING + SIDE_OFFSET)
                                                for k, s in enumerate(SIDES)}
DEFAULT_SIDE = "middle"  # where the expert takes the cube back without a fact
EPISODE_STEPS = 60
CUBE_CENTRE_Z = 0.03  # the seen pixels' mean lies between the cube's top face (4 cm) and its front (2 cm)
MIN_CUBE_PIXELS = 4


def side_of(y: float) -> str:
    """The side whose centre is nearest to a start at ``y`` (metres, world frame)."""
    return min(SIDES, key=lambda s: abs(SIDE_CENTRES[s][1] - y))


def green_mask(rgb: np.ndarray) -> np.ndarray:
    """The cube's pixels: saturated green (its faces render as (4, 231, 4) and (0, 148, 0)); the wood, the
    red and white target rings and the robot never pass."""
    rgb = np.asarray(rgb).astype(np.int16)
    return (rgb[..., 1] >= 100) & (rgb[..., 0] <= 60) & (rgb[..., 2] <= 60)


def cube_on_table(rgb: np.ndarray, intrinsic: np.ndarray, extrinsic: np.ndarray,
                  plane_z: float = CUBE_CENTRE_Z) -> np.ndarray | None:
    """The table point (x, y) under the green cube's pixels in one frame (H, W, 3), or None if it is out of
    sight: the pixels' mean is cast along the camera ray (OpenCV ``intrinsic`` 3x3, world-to-camera
    ``extrinsic`` 3x4) onto the plane ``z = plane_z``."""
    mask = green_mask(rgb)
    if mask.sum() < MIN_CUBE_PIXELS:
        return None
    row, col = np.argwhere(mask).mean(axis=0) + 0.5
    rotation, translation = np.asarray(extrinsic)[:, :3], np.asarray(extrinsic)[:, 3]
    ray = rotation.T @ (np.linalg.inv(np.asarray(intrinsic)) @ np.array([col, row, 1.0]))
    origin = -rotation.T @ translation
    if abs(ray[2]) < 1e-9:
        return None
    point = origin + (plane_z - origin[2]) / ray[2] * ray
    return point[:2]


class StartWriter:
    """Writes ``the cube started at the {side}.`` from the reset frame's sighting of the cube (``seen_start``,
    what the base camera showed); later frames change nothing (the cube moves, its start does not)."""

    relations = {"start": (MemoryType.OTHER, CUE_RELATION)}

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        seen = frame.state.get("seen_start") if frame.steps == 0 else None
        return [] if seen is None else [(0, {("start", CUE_ENTITY): side_of(float(seen[1]))})]


class TakeItBackObservation(DetectorObservation):
    """A TakeItBack observation cut to a controller's view: the joints, the hand, the cameras, the cube's
    position (``extra/cube_position``, (B, 3)), and the two targets a camera tells apart by colour
    (``extra/target_positions`` (B, 2, 3) and ``extra/target_visible`` (B, 2): the red one, then the
    purple one that replaces it). The start's marker, hidden from the cameras, is not among them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, lambda base: [base.goal_region, base.changed_goal_region], "target")
        batch = int(getattr(env.unwrapped, "num_envs", 1))
        self.observation_space["extra"]["cube_position"] = spaces.Box(-np.inf, np.inf, (batch, 3), np.float32)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        out["extra"]["cube_position"] = stack_positions([self.env.unwrapped.cube.pose.p], like=obs["extra"]["tcp_pose"])[:, 0]
        return out


class TakeItBackTask(MikasaCueTask):
    """MIKASA-Robo-VLA's TakeItBack-VLA-v0: bring the cube to the red target, then back to its start."""

    field, detector_key = "side", "target"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, CUE_RELATION, CUE_FACT
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, SIDES
    observation_wrapper: ClassVar = TakeItBackObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives TakeItBack none
    perceives_every_step = False  # the start is read from the reset frame alone: the camera renders at decisions
    max_control_steps = EPISODE_STEPS

    def __init__(self, env_id: str = "TakeItBack-VLA-v0"):
        if env_id != "TakeItBack-VLA-v0":
            raise ValueError(f"unknown TakeItBack task {env_id!r}; expected 'TakeItBack-VLA-v0'")
        super().__init__(env_id, len(SIDES))

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs = to_numpy(obs)
        base = env.unwrapped
        starts = as_numpy(base.oracle_info).reshape(-1, 3)  # privileged: for metrics only
        success = as_numpy(info["success"]).reshape(-1)
        seen: list[np.ndarray | None] = [None] * len(success)
        if reset:  # what the base camera saw of the cube before anything moved
            rgb = obs["sensor_data"]["base_camera"]["rgb"]
            seen = [cube_on_table(rgb[i], BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC) for i in range(len(success))]
        return [EnvFrame(select_obs(obs, i), {"side": side_of(float(starts[i, 1])), "start": starts[i, :2],
                                              "seen_start": seen[i]}, None, bool(success[i]))
                for i in range(len(success))]

    def writer(self, source: str = "seeded") -> StartWriter:
        return StartWriter()

    def episode(self, frame: EnvFrame) -> Episode:
        side = frame.state["side"]
        x, y = (float(v) for v in frame.state["start"])
        return Episode(self.cue_entity, side, ((self.cue_key, side),), {"start_x": x, "start_y": y})

    def wrong_facts(self, episode: Episode) -> list[str]:
        """The side farthest from the start: MIKASA's 8 cm also counts a neighbouring side's centre for the starts
        near it, so a neighbour is not always wrong; the far side (right for left, left for right, and for a
        middle start the side away from it) is 10 cm or more off."""
        y = float(episode.details["start_y"])
        far = max(SIDES, key=lambda side: abs(SIDE_CENTRES[side][1] - y))
        return [self.cue_fact.format(side=far)]

    def expert(self) -> CarryBackController:
        return CarryBackController(SIDE_CENTRES, DEFAULT_SIDE, PROMPT_TEMPLATE)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.with_state_extra(demo_layout.demo_features(("red", "purple"), with_images, key="target"),
                                            "cube")

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.append_state(demo_layout.demo_frame(obs, with_images, key="target"),
                                        obs["extra"]["cube_position"])


__all__ = ["CUE_FACT", "DEFAULT_SIDE", "EPISODE_STEPS", "INSTRUCTION", "PROMPT_TEMPLATE", "SIDES", "SIDE_CENTRES",
           "StartWriter", "TakeItBackObservation", "TakeItBackTask", "cube_on_table", "green_mask", "side_of"]
