"""MIKASA-Robo-VLA's TraceShape tasks (Easy, Medium, Hard) as sb3-memret tasks: a path a red cube traced once must
be remembered, to trace it again with a green cube.

The procedural-memory tasks. The env is MIKASA's own (``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``,
128x128 cameras, the ``normalized_dense`` reward, success counted once per episode, evaluation at seeds
4242424242 + i. MIKASA's wrapper table gives them no ``CurriculumPhaseNoopActionWrapper``: actions act from the first
step. The lamp's bulbs are a mesh that MIKASA's wheel leaves out: ``lamp_asset`` puts the project's copy of MIKASA's
file in place before the env is made.

**Episode:** a red and a green cube (4 cm) stand on the table, a white lamp 25 cm beyond the shape's centre. After
3-8 steps the lamp turns red and the red cube traces a closed path, one of MIKASA's 64 waypoints a control step: a
circle, a square or an equilateral triangle (``paths``). Then the lamp turns green, the red cube disappears, and the
robot must carry the green cube round the same path: MIKASA counts each of 12 checkpoints (every 5th waypoint) once
the cube's xy passes within 3.5 cm of it after the lamp turned green, and succeeds when all are visited and the cube
is back within 3.5 cm of the first. Episodes last 250, 300 or 350 control steps; MIKASA's env ends one at success.

**Randomisations** (MIKASA's): the shape (Easy: circles; Medium: circles or squares; Hard: any of the three), its
radius (7.8-13 cm), centre (x -15 to -5 cm, y -10 to 10 cm) and rotation (any); the demonstration's start (3-8
steps); the green cube 16 cm nearer the robot than the centre, the lamp with the centre; the arm's initial joints.

**Success:** MIKASA's: every checkpoint visited after the lamp turned green, then the cube back by the first.

**Facts:** one, read from the base camera at every step of the demonstration: the red cube renders in two flat
shades with equal green and blue channels, (216, 110, 110) and (138, 70, 70) (``red_cube_pixel``; the wood's blue
channel is 40 below its green, the lamp's red bulb has no green), and its pixels' mean is cast onto the table (z =
2 cm) through the base camera's shipped calibration (``core.calibration``); the lamp's colour (``read_lit_colour``)
says when the demonstration starts (red) and ends (green). The n-th frame after the lamp turned red shows waypoint n,
so each sighting has its path fraction, and ``fit_path`` recovers the shape, centre and start by least squares, with
frames the arm hides left out. It is written when the lamp turns green: ``the red cube traced a square round -112 31
mm from -190 -40 mm.`` (the centre, then the start, in millimetres on the table). Decoys are worded alike about other
things. The controller sees ``TraceShapeObservation`` only (never the waypoints, ``oracle_info`` or the lamp), so the
path reaches it only through its prompt.

**The expert** (``TraceShapeController``) grasps the green cube and carries it round the path its prompt names;
without one it holds the cube, a guess that never succeeds. It reads the green cube's position from a detector, as
the other MIKASA experts do (a simulated detector: a privileged upper bound). The wrong condition names the same
path moved 8 cm towards the table's middle (in y).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, NamedTuple

import gymnasium as gym
import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import SIGNED_NUMBER, PromptTemplate
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC, BASE_CAMERA_SIZE
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.lamp_perception import read_lit_colour
from sb3_memret.tasks.mikasa.core.layout_perception import LAYOUT_PLANE_Z, table_points
from sb3_memret.tasks.mikasa.core.perception import DetectorObservation
from sb3_memret.tasks.mikasa.trace_shape.expert import TraceShapeController
from sb3_memret.tasks.mikasa.trace_shape.paths import MIN_SIGHTINGS, NUM_WAYPOINTS, SHAPES, TracedPath, fit_path

# MIKASA's LANGUAGE_INSTRUCTION in the prompt contract's form: lowercase, its two sentences joined by a semicolon
INSTRUCTION = ("watch the red cube trace a shape on the table; when the lamp turns green, pick up the green cube and "
               "trace exactly the same shape.")
FACT_TEMPLATE = "the {entity} traced a {shape} round {cx} {cy} mm from {sx} {sy} mm."
CUE_ENTITY = "red cube"
CUE_RELATION = "traced_a"  # OTHER's template, "the {entity} {relation} {value}.", reads FACT_TEMPLATE
PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(FACT_TEMPLATE,),
                                 fields=tuple((name, SIGNED_NUMBER) for name in ("cx", "cy", "sx", "sy")))
# MIKASA's variants: the shapes in play and the episode's control steps (its registered max_episode_steps)
VARIANTS: dict[str, tuple[tuple[str, ...], int]] = {
    "TraceShapeEasy-VLA-v0": (SHAPES[:1], 250), "TraceShapeMedium-VLA-v0": (SHAPES[:2], 300),
    "TraceShapeHard-VLA-v0": (SHAPES, 350),
}
PRE_DEMO_STEPS = (3, 8)  # MIKASA's: the lamp turns red after this many steps (inclusive)
MIN_RED_PIXELS = 4  # the red cube covered 20-40 pixels at 128x128 where measured
WRONG_SHIFT_MM = 80  # the wrong condition's path: moved this far in y, towards the table's middle
TRUE_TOLERANCE_MM = 10  # a written path is the episode's when its centre and start are this close (metrics only)
_VALUE = re.compile(r"(?P<shape>[a-z]+) round (?P<cx>-?\d+) (?P<cy>-?\d+) mm from (?P<sx>-?\d+) (?P<sy>-?\d+) mm")


def path_value(path: TracedPath) -> str:
    """The fact's value for ``path`` (``square round -112 31 mm from -190 -40 mm``)."""
    return f"{path.shape} round {path.centre[0]} {path.centre[1]} mm from {path.start[0]} {path.start[1]} mm"


def parse_path_value(value: str) -> TracedPath | None:
    """The path a fact's value names, or None when it names none."""
    m = _VALUE.fullmatch(value)
    if m is None or m["shape"] not in SHAPES:
        return None
    return TracedPath(m["shape"], (int(m["cx"]), int(m["cy"])), (int(m["sx"]), int(m["sy"])))


def red_cube_pixel(rgb: np.ndarray) -> np.ndarray | None:
    """The (row, col) pixel centre of the red cube in one base-camera frame (H, W, 3), or None when it shows fewer
    than ``MIN_RED_PIXELS``: its flat shades have equal green and blue, red 50 or more above them."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"expected one (H, W, 3) frame, got shape {rgb.shape}")
    r, g, b = (rgb[..., i].astype(np.int16) for i in range(3))
    mask = (np.abs(g - b) <= 3) & (r - g >= 50) & (g >= 40)
    if mask.sum() < MIN_RED_PIXELS * rgb.shape[0] * rgb.shape[1] / BASE_CAMERA_SIZE ** 2:
        return None
    return np.argwhere(mask).mean(axis=0) + 0.5


class TracePercept(NamedTuple):
    """One step's base-camera reading: the lamp's colour (None: white) and where the red cube stands (x, y), if
    seen."""

    lamp: str | None
    red_cube: tuple[float, float] | None


class PathWriter:
    """Writes ``the red cube traced a square round ... mm from ... mm.`` at the step the lamp is first seen green,
    from the red cube's sightings since it was first seen red (the n-th such step shows waypoint n): ``fit_path`` over
    ``shapes``. Fewer than ``MIN_SIGHTINGS``, nothing written. The reset frame (``steps == 0``) starts an episode."""

    relations = {"path": (MemoryType.OTHER, CUE_RELATION)}

    def __init__(self, shapes: tuple[str, ...] = SHAPES):
        self.shapes = shapes
        self._start()

    def _start(self) -> None:
        self.t, self.red_from, self.written = 0, None, False
        self.sightings: list[tuple[int, tuple[float, float]]] = []

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self._start()
        out = []
        for step, percept in frame.timed_percepts():
            if self.written:
                break
            now = self.t + step
            if percept.lamp == "red":
                self.red_from = now if self.red_from is None else self.red_from
                if percept.red_cube is not None and now - self.red_from < NUM_WAYPOINTS:
                    self.sightings.append((now - self.red_from, percept.red_cube))
            elif percept.lamp == "green" and self.red_from is not None:
                self.written = True
                if len(self.sightings) >= MIN_SIGHTINGS:
                    index, points = zip(*self.sightings)
                    path, _ = fit_path(np.array(index) / NUM_WAYPOINTS, np.array(points), self.shapes)
                    out.append((step, {("path", CUE_ENTITY): path_value(path)}))
        self.t += frame.steps
        return out


@dataclass(frozen=True)
class PathEpisode(Episode):
    """A TraceShape episode's ground truth: a written path is true when it names the episode's shape and its centre
    and start lie within ``TRUE_TOLERANCE_MM`` of the episode's (a reading from pixels is never exact)."""

    def is_true(self, entry: MemoryEntry) -> bool:
        seen, truth = parse_path_value(entry.value), self.details["path"]
        if entry.key != (MemoryType.OTHER, CUE_ENTITY, CUE_RELATION) or seen is None or seen.shape != truth.shape:
            return False
        off = np.abs(np.array([*seen.centre, *seen.start]) - np.array([*truth.centre, *truth.start]))
        return bool(off.max() <= TRUE_TOLERANCE_MM)


class TraceShapeObservation(DetectorObservation):
    """A TraceShape observation cut to a controller's view: the joints, the hand, the cameras and the green cube
    (``extra/cube_positions`` (B, 1, 3), ``extra/cube_visible``). The red cube, the waypoints, the checkpoints and the
    lamp are not among them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, lambda base: [base.green_cube], "cube")


class TraceShapeTask(MikasaCueTask):
    """MIKASA-Robo-VLA's TraceShape{Easy,Medium,Hard}-VLA-v0 (``VARIANTS``): carry the green cube round the path the
    red cube traced."""

    field, detector_key, truth_attribute = "shape", "cube", "shape_type"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, CUE_RELATION, FACT_TEMPLATE
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, SHAPES
    observation_wrapper: ClassVar = TraceShapeObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives TraceShape none
    # MIKASA's env ends an episode at its success, while its dense reward pays 0.2-0.3 a step for holding the cube by
    # the path: a learner would earn more by never closing it. Success stands for an absorbing state paying what
    # MIKASA pays at a success step (its bonus, 30 / 30), as the decision env's absorbing_success_value adds.
    ends_at_success = True
    success_reward = 1.0

    def __init__(self, env_id: str = "TraceShapeEasy-VLA-v0"):
        if env_id not in VARIANTS:
            raise ValueError(f"unknown TraceShape task {env_id!r}; expected one of {sorted(VARIANTS)}")
        shapes, steps = VARIANTS[env_id]
        super().__init__(env_id, len(shapes))
        self.max_control_steps = steps

    # ------------------------------------------------------------ simulation
    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, obs_mode: str = "rgb",
                 render_backend: str = "cpu", **kwargs: Any) -> gym.Env:
        from sb3_memret.tasks.mikasa.core.lamp_asset import install_lamp_asset

        install_lamp_asset()  # the lamp's bulb mesh, which MIKASA's wheel leaves out
        return super().make_env(max_episode_steps=max_episode_steps, num_envs=num_envs, obs_mode=obs_mode,
                                render_backend=render_backend, **kwargs)

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs = to_numpy(obs)
        base = env.unwrapped  # privileged: the true path, for metrics and the fixed conditions only
        shapes, waypoints = as_numpy(base.shape_type).reshape(-1), as_numpy(base.waypoints)
        success = as_numpy(info["success"]).reshape(-1)
        fractions = np.arange(NUM_WAYPOINTS) / NUM_WAYPOINTS
        paths = [fit_path(fractions, waypoints[i], (SHAPES[int(shapes[i])],))[0] for i in range(len(success))]
        return [EnvFrame(select_obs(obs, i), {"path": paths[i]}, None, bool(success[i])) for i in range(len(success))]

    def perceive(self, env: gym.Env, obs: Any) -> TracePercept:
        rgb = as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0]
        pixel = red_cube_pixel(rgb)
        point = None if pixel is None else table_points(pixel[None], BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC,
                                                        LAYOUT_PLANE_Z)[0]
        return TracePercept(read_lit_colour(rgb), None if point is None else (float(point[0]), float(point[1])))

    def perception_window(self, env: gym.Env) -> int | None:
        """The latest demonstration's end (MIKASA's ``PRE_DEMO_STEPS`` and its 64 waypoints), and one step more."""
        pre = getattr(env.unwrapped, "PRE_DEMO_STEPS", PRE_DEMO_STEPS)
        return int(max(pre)) + NUM_WAYPOINTS + 1

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> PathWriter:
        return PathWriter(self.words)

    def episode(self, frame: EnvFrame) -> Episode:
        path = frame.state["path"]
        return PathEpisode(self.cue_entity, path.shape, ((self.cue_key, path_value(path)),), {"path": path})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` facts worded as the red cube's about other things, each a path of MIKASA's
        ranges (``the key traced a circle round ... mm from ... mm.``); the red cube's comes only from the camera."""
        vocab = sorted(set(seeding.vocabulary) - {CUE_ENTITY})
        decoys = []
        for word in rng.choice(vocab, size=seeding.location_decoys, replace=False):
            centre = (int(rng.integers(-150, -49)), int(rng.integers(-100, 101)))
            radius, angle = rng.uniform(78, 130), rng.uniform(0, 2 * np.pi)
            start = (int(round(centre[0] + radius * np.cos(angle))), int(round(centre[1] + radius * np.sin(angle))))
            path = TracedPath(str(rng.choice(self.words)), centre, start)
            decoys.append(MemoryEntry.create(MemoryType.OTHER, str(word), CUE_RELATION, path_value(path), 0))
        return decoys

    # ------------------------------------------------------------ prompts and controllers
    def oracle_facts(self, episode: Episode) -> list[str]:
        return [f"the {CUE_ENTITY} traced a {path_value(episode.details['path'])}."]

    def wrong_facts(self, episode: Episode) -> list[str]:
        """The same path moved ``WRONG_SHIFT_MM`` in y towards the table's middle: none of its checkpoints is within
        MIKASA's 3.5 cm of the true ones."""
        path = episode.details["path"]
        shifted = path.moved(0, -WRONG_SHIFT_MM if path.centre[1] > 0 else WRONG_SHIFT_MM)
        return [f"the {CUE_ENTITY} traced a {path_value(shifted)}."]

    def expert(self) -> TraceShapeController:
        """The tracing expert; without a path it holds the green cube (never succeeds)."""
        return TraceShapeController(PROMPT_TEMPLATE)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.demo_features(("green",), with_images, key="cube")

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.demo_frame(obs, with_images, key="cube")


__all__ = ["FACT_TEMPLATE", "INSTRUCTION", "PROMPT_TEMPLATE", "PathEpisode", "PathWriter", "TraceShapeObservation",
           "TracePercept", "TraceShapeTask", "VARIANTS", "parse_path_value", "path_value", "red_cube_pixel"]
