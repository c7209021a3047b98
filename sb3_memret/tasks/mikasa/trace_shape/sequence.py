"""MIKASA-Robo-VLA's TraceShapeSeq tasks (Easy, Medium, Hard) as sb3-memret tasks: a sequence of paths a red cube
traced must be remembered, traced again in order, and what has been traced kept track of, before the submission.

The long procedural-memory tasks (1500 control steps). MIKASA's env with its protocol, as TraceShape's (``task``).

**Episode:** as TraceShape, but the red cube traces 2-5 closed paths one after another round one centre, each a
circle, square or triangle of its own radius and rotation (64 steps each, the lamp red throughout); then the lamp turns
green and the robot must carry the green cube round each path in order: MIKASA checks only the active path's 12
checkpoints, and closes it (making the next one active) when all are visited and the cube is back within 3.5 cm of
its start. With every path closed, a press of the button (a cap on a 13 cm base, 27 cm beyond and 16 cm left of the
centre) succeeds; a press before fails. MIKASA's env ends the episode at the first press.

**Randomisations** (MIKASA's): the number of paths (2-5, uniform), each one's shape (Easy: circles; Medium: circles
or squares; Hard: any), radius (7.8-13 cm) and rotation; the centre (x -15 to -5 cm, y -10 to 10 cm); the
demonstration's start (3-8 steps); the arm's initial joints.

**Success:** MIKASA's: the button pressed with every path closed in order.

**Facts:** the sequence, one fact read from the base camera over the demonstration as TraceShape's path (the button's
pink cap, whose shades also have equal green and blue, left out: ``red_cube_pixel_beside_button``): the n-th
frame after the lamp turned red shows path n // 64 at its waypoint n % 64; each path is fitted alone (``fit_path``)
and the centres averaged. Written when the lamp turns green: ``the red cube traced round -112 31 mm, a circle from
-190 -40 mm, then a square from 10 20 mm.`` (one fact carries the whole sequence, as FindImposter's set does: K = 1).
**Progress as memory**: which path is active is not in sight (MIKASA's checkpoint tallies), so a controller that
reads only the frame and its prompt cannot tell how far it has got. The writer also writes ``the green cube traced two
paths.`` (TASK_PROGRESS, replaced at each closure), replaying MIKASA's rule on the TCP's position (proprioception;
the cube is held under it) while the fingers hold something, with a 2.5 cm radius, stricter than MIKASA's 3.5 cm, so
that what it counts closed MIKASA has closed too. The fixed conditions state the progress from MIKASA's own tally
(``Task.progress_facts``).

**The expert** (``TraceSequenceController``) traces the path after those its progress fact counts, then lets the cube
go and presses the button; without a sequence it holds the cube. It reads the green cube's and the button's positions
from a detector (a simulated detector: a privileged upper bound). The wrong condition names the sequence round a
centre moved 8 cm towards the table's middle (in y).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import SIGNED_NUMBER, PromptTemplate
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.lamp_perception import read_lit_colour
from sb3_memret.tasks.mikasa.core.layout_perception import LAYOUT_PLANE_Z, table_points
from sb3_memret.tasks.mikasa.core.perception import DetectorObservation, stack_positions
from sb3_memret.tasks.mikasa.trace_shape.sequence_expert import ORDINAL_COUNTS, TraceSequenceController
from sb3_memret.tasks.mikasa.trace_shape.paths import MIN_SIGHTINGS, NUM_WAYPOINTS, SHAPES, TracedPath, fit_path
from sb3_memret.tasks.mikasa.trace_shape.task import TRUE_TOLERANCE_MM, WRONG_SHIFT_MM, red_cube_pixel

INSTRUCTION = ("watch the red cube trace a sequence of shapes; when the lamp turns green, pick up the green cube and "
               "trace the same sequence in order; after finishing all shapes, press the button to submit your answer.")
MIN_PATHS, MAX_PATHS = 2, 5  # MIKASA's MIN_SEQUENCE_LENGTH, MAX_SEQUENCE_LENGTH
CUE_ENTITY, PROGRESS_ENTITY, RELATION = "red cube", "green cube", "traced"
PROGRESS_TEMPLATE = "the {entity} traced {paths}."
PROGRESS_WORDINGS = {(MemoryType.TASK_PROGRESS, word): "the {entity} traced {value}." for word in ORDINAL_COUNTS}
VISIT_RADIUS = 0.025  # the writer's checkpoint radius on the TCP (MIKASA's: 3.5 cm on the cube)
HOLD_GAP = (0.02, 0.06)  # the fingers' gap while they hold the cube


def sequence_template(n: int) -> str:
    """The fact template of a sequence of ``n`` paths round one centre."""
    items = ", then ".join(f"a {{shape{i}}} from {{sx{i}}} {{sy{i}}} mm" for i in range(1, n + 1))
    return f"the {{entity}} traced round {{cx}} {{cy}} mm, {items}."


PROMPT_TEMPLATE = PromptTemplate(
    instructions=(INSTRUCTION,),
    fact_templates=(*(sequence_template(n) for n in range(MIN_PATHS, MAX_PATHS + 1)), PROGRESS_TEMPLATE),
    fields=tuple((name, SIGNED_NUMBER) for name in ("cx", "cy", *(f"s{axis}{i}" for i in range(1, MAX_PATHS + 1)
                                                                    for axis in "xy"))))
VARIANTS: dict[str, tuple[tuple[str, ...], int]] = {
    "TraceShapeSeqEasy-VLA-v0": (SHAPES[:1], 1500), "TraceShapeSeqMedium-VLA-v0": (SHAPES[:2], 1500),
    "TraceShapeSeqHard-VLA-v0": (SHAPES, 1500),
}
_ITEM = re.compile(r"a (?P<shape>[a-z]+) from (?P<sx>-?\d+) (?P<sy>-?\d+) mm")
_VALUE = re.compile(r"round (?P<cx>-?\d+) (?P<cy>-?\d+) mm, (?P<items>.+)")


BUTTON_SHADE_RATIO = 0.6  # the button cap's shades, (211, 136, 136) and (135, 87, 87): green / red 0.64; the cube's 0.51


def red_cube_pixel_beside_button(rgb: np.ndarray) -> np.ndarray | None:
    """``red_cube_pixel`` in a frame that also shows the button's pink cap, whose flat shades have equal green and blue
    too: its pixels (green over red above ``BUTTON_SHADE_RATIO``) are blanked first."""
    rgb = np.array(rgb, copy=True)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"expected one (H, W, 3) frame, got shape {rgb.shape}")
    r, g, b = (rgb[..., i].astype(np.float64) for i in range(3))
    rgb[(np.abs(g - b) <= 3) & (r >= 100) & (g > BUTTON_SHADE_RATIO * r)] = 0
    return red_cube_pixel(rgb)


def sequence_value(paths: list[TracedPath]) -> str:
    """The sequence fact's value (``round -112 31 mm, a circle from -190 -40 mm, then a square from 10 20 mm``): the
    paths' common centre, then each one's shape and start."""
    if not MIN_PATHS <= len(paths) <= MAX_PATHS or len({p.centre for p in paths}) != 1:
        raise ValueError(f"a sequence is {MIN_PATHS}-{MAX_PATHS} paths round one centre, got {paths}")
    items = ", then ".join(f"a {p.shape} from {p.start[0]} {p.start[1]} mm" for p in paths)
    return f"round {paths[0].centre[0]} {paths[0].centre[1]} mm, {items}"


def parse_sequence_value(value: str) -> list[TracedPath] | None:
    """The paths a sequence fact's value names, or None when it names none."""
    m = _VALUE.fullmatch(value)
    if m is None:
        return None
    items = m["items"].split(", then ")
    parsed = [_ITEM.fullmatch(item) for item in items]
    if not all(parsed) or not all(p["shape"] in SHAPES for p in parsed):
        return None
    centre = (int(m["cx"]), int(m["cy"]))
    return [TracedPath(p["shape"], centre, (int(p["sx"]), int(p["sy"]))) for p in parsed]


def sequence_fact(paths: list[TracedPath]) -> str:
    return f"the {CUE_ENTITY} {RELATION} {sequence_value(paths)}."


class SeqPercept(NamedTuple):
    """One step's reading: the lamp's colour (base camera), where the red cube stands (x, y; base camera), where the
    TCP is (x, y; proprioception) and the fingers' gap (proprioception)."""

    lamp: str | None
    red_cube: tuple[float, float] | None
    tcp: tuple[float, float]
    gap: float


class PathSequenceWriter:
    """Writes the sequence fact when the lamp is first seen green, from the red cube's sightings since it turned red,
    then ``the green cube traced two paths.`` at each path the TCP is seen to close (MIKASA's rule, ``VISIT_RADIUS``)
    while the fingers hold the cube. The reset frame (``steps == 0``) starts an episode."""

    relations = {"sequence": (MemoryType.OTHER, RELATION), "progress": (MemoryType.TASK_PROGRESS, RELATION)}

    def __init__(self, shapes: tuple[str, ...] = SHAPES):
        self.shapes = shapes
        self._start()

    def _start(self) -> None:
        self.t, self.red_from, self.paths, self.done = 0, None, None, 0
        self.sightings: dict[int, list[tuple[int, tuple[float, float]]]] = {}
        self.visited = np.zeros(0, dtype=bool)

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self._start()
        out = []
        for step, percept in frame.timed_percepts():
            now = self.t + step
            if self.paths is None:
                out += [(step, predicates) for predicates in self._cue(percept, now)]
            elif self.done < len(self.paths) and HOLD_GAP[0] <= percept.gap <= HOLD_GAP[1]:
                out += [(step, predicates) for predicates in self._progress(percept)]
        self.t += frame.steps
        return out

    def _cue(self, percept: SeqPercept, now: int) -> list[Predicates]:
        if percept.lamp == "red":
            self.red_from = now if self.red_from is None else self.red_from
            k = now - self.red_from
            if percept.red_cube is not None:
                self.sightings.setdefault(k // NUM_WAYPOINTS, []).append((k % NUM_WAYPOINTS, percept.red_cube))
            return []
        if percept.lamp != "green" or self.red_from is None:
            return []
        n = (now - self.red_from) // NUM_WAYPOINTS
        self.paths = []  # read once: nothing more is written about the cue
        if not MIN_PATHS <= n <= MAX_PATHS or any(len(self.sightings.get(j, ())) < MIN_SIGHTINGS for j in range(n)):
            return []
        fits = []
        for j in range(n):
            index, points = zip(*self.sightings[j])
            fits.append(fit_path(np.array(index) / NUM_WAYPOINTS, np.array(points), self.shapes)[0])
        centre = tuple(int(round(v)) for v in np.mean([p.centre for p in fits], axis=0))
        self.paths = [TracedPath(p.shape, centre, p.start) for p in fits]
        self.visited = np.zeros(len(self.paths[0].checkpoints()), dtype=bool)
        return [{("sequence", CUE_ENTITY): sequence_value(self.paths)}]

    def _progress(self, percept: SeqPercept) -> list[Predicates]:
        checkpoints = self.paths[self.done].checkpoints()
        near = np.linalg.norm(checkpoints - np.asarray(percept.tcp), axis=1) < VISIT_RADIUS
        self.visited |= near
        if not (self.visited.all() and near[0]):
            return []
        self.done += 1
        self.visited = np.zeros(len(checkpoints), dtype=bool)
        return [{("progress", PROGRESS_ENTITY): ORDINAL_COUNTS[self.done - 1]}]


@dataclass(frozen=True)
class SequenceEpisode(Episode):
    """A TraceShapeSeq episode's ground truth: a written sequence is true when it names the episode's shapes in order
    with every start and the centre within ``TRUE_TOLERANCE_MM`` of the episode's."""

    def is_true(self, entry: MemoryEntry) -> bool:
        seen, truth = parse_sequence_value(entry.value), self.details["paths"]
        if entry.key != (MemoryType.OTHER, CUE_ENTITY, RELATION) or seen is None or len(seen) != len(truth):
            return False
        if [p.shape for p in seen] != [p.shape for p in truth]:
            return False
        off = [np.abs(np.array([*a.centre, *a.start]) - np.array([*b.centre, *b.start])).max()
               for a, b in zip(seen, truth)]
        return bool(max(off) <= TRUE_TOLERANCE_MM)


class TraceSequenceObservation(DetectorObservation):
    """A TraceShapeSeq observation cut to a controller's view: the joints, the hand, the cameras, the green cube
    (``extra/cube_positions`` (B, 1, 3), ``extra/cube_visible``) and the button's cap (``extra/button_position``,
    (B, 3)). The red cube, the paths, MIKASA's tallies and the lamp are not among them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, lambda base: [base.green_cube], "cube")
        batch = int(getattr(env.unwrapped, "num_envs", 1))
        self.observation_space["extra"]["button_position"] = spaces.Box(-np.inf, np.inf, (batch, 3), np.float32)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        out["extra"]["button_position"] = stack_positions([self.env.unwrapped.button_cap.pose.p],
                                                          like=obs["extra"]["tcp_pose"])[:, 0]
        return out


class TraceShapeSeqTask(MikasaCueTask):
    """MIKASA-Robo-VLA's TraceShapeSeq{Easy,Medium,Hard}-VLA-v0 (``VARIANTS``): carry the green cube round each path
    the red cube traced, in order, then press the button."""

    field, detector_key, truth_attribute = "shape1", "cube", "shape_sequence"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, RELATION, sequence_template(MIN_PATHS)
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, SHAPES
    observation_wrapper: ClassVar = TraceSequenceObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives TraceShapeSeq none
    wordings = PROGRESS_WORDINGS
    ends_at_success = True  # as TraceShape: success absorbing at what MIKASA pays then (its bonus, 40 / 40)
    success_reward = 1.0

    def __init__(self, env_id: str = "TraceShapeSeqEasy-VLA-v0"):
        if env_id not in VARIANTS:
            raise ValueError(f"unknown TraceShapeSeq task {env_id!r}; expected one of {sorted(VARIANTS)}")
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
        base = env.unwrapped  # privileged: the true paths and MIKASA's tally, for metrics and the fixed conditions only
        lengths, shapes = as_numpy(base.sequence_len).reshape(-1), as_numpy(base.shape_sequence)
        waypoints, closed = as_numpy(base.waypoints), as_numpy(base.shape_closed)
        success = as_numpy(info["success"]).reshape(-1)
        fractions = np.arange(NUM_WAYPOINTS) / NUM_WAYPOINTS
        frames = []
        for i in range(len(success)):
            n = int(lengths[i])
            paths = [fit_path(fractions, waypoints[i, j], (SHAPES[int(shapes[i, j])],))[0] for j in range(n)]
            centre = paths[0].centre
            paths = [TracedPath(p.shape, centre, p.start) for p in paths]
            frames.append(EnvFrame(select_obs(obs, i), {"paths": paths, "closed": int(closed[i, :n].sum())}, None,
                                   bool(success[i])))
        return frames

    def perceive(self, env: gym.Env, obs: Any) -> SeqPercept:
        rgb = as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0]
        pixel = red_cube_pixel_beside_button(rgb)
        point = None if pixel is None else table_points(pixel[None], BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC,
                                                        LAYOUT_PLANE_Z)[0]
        tcp = as_numpy(obs["extra"]["tcp_pose"]).reshape(-1)
        gap = float(as_numpy(obs["agent"]["qpos"]).reshape(-1)[7:9].sum())
        return SeqPercept(read_lit_colour(rgb), None if point is None else (float(point[0]), float(point[1])),
                          (float(tcp[0]), float(tcp[1])), gap)

    def perception_window(self, env: gym.Env) -> int | None:
        """The whole episode: the writer counts the paths the TCP closes at every step."""
        return None

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> PathSequenceWriter:
        return PathSequenceWriter(self.words)

    def episode(self, frame: EnvFrame) -> Episode:
        paths = frame.state["paths"]
        key = (MemoryType.OTHER, CUE_ENTITY, RELATION)
        return SequenceEpisode(self.cue_entity, f"{len(paths)} paths", ((key, sequence_value(paths)),),
                               {"paths": paths})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` sequences of MIKASA's ranges worded as the red cube's about other things (``the
        key traced round ...``); the red cube's comes only from the camera."""
        vocab = sorted(set(seeding.vocabulary) - {CUE_ENTITY, PROGRESS_ENTITY})
        decoys = []
        for word in rng.choice(vocab, size=seeding.location_decoys, replace=False):
            centre = (int(rng.integers(-150, -49)), int(rng.integers(-100, 101)))
            paths = []
            for _ in range(int(rng.integers(MIN_PATHS, MAX_PATHS + 1))):
                radius, angle = rng.uniform(78, 130), rng.uniform(0, 2 * np.pi)
                start = (int(round(centre[0] + radius * np.cos(angle))), int(round(centre[1] + radius * np.sin(angle))))
                paths.append(TracedPath(str(rng.choice(self.words)), centre, start))
            decoys.append(MemoryEntry.create(MemoryType.OTHER, str(word), RELATION, sequence_value(paths), 0))
        return decoys

    # ------------------------------------------------------------ prompts and controllers
    def oracle_facts(self, episode: Episode) -> list[str]:
        return [sequence_fact(episode.details["paths"])]

    def wrong_facts(self, episode: Episode) -> list[str]:
        """The sequence round a centre moved ``WRONG_SHIFT_MM`` in y towards the table's middle."""
        paths = episode.details["paths"]
        shift = -WRONG_SHIFT_MM if paths[0].centre[1] > 0 else WRONG_SHIFT_MM
        return [sequence_fact([p.moved(0, shift) for p in paths])]

    def progress_facts(self, frame: EnvFrame) -> list[str]:
        """``the green cube traced two paths.`` from MIKASA's own tally, once a path is closed."""
        closed = frame.state["closed"]
        return [f"the {PROGRESS_ENTITY} {RELATION} {ORDINAL_COUNTS[closed - 1]}."] if closed else []

    def expert(self) -> TraceSequenceController:
        """The sequence expert; without a sequence it holds the green cube (never succeeds)."""
        return TraceSequenceController(PROMPT_TEMPLATE)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.with_state_extra(demo_layout.demo_features(("green",), with_images, key="cube"), "button")

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.append_state(demo_layout.demo_frame(obs, with_images, key="cube"),
                                        obs["extra"]["button_position"])


__all__ = ["INSTRUCTION", "PROGRESS_WORDINGS", "PROMPT_TEMPLATE", "PathSequenceWriter", "SeqPercept",
           "SequenceEpisode", "TraceSequenceObservation", "TraceShapeSeqTask", "VARIANTS", "parse_sequence_value",
           "red_cube_pixel_beside_button",
           "sequence_fact", "sequence_template", "sequence_value"]
