"""MIKASA TraceShape: MIKASA's paths and their fit, the red cube read from pixels, the writer, the controller's view,
the tracing expert, the task's conditions (the shipped calibration: test_mikasa_calibration.py). Development seeds
(5000+) only."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, leaked_keys

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt, parse_prompt  # noqa: E402
from sb3_memret.evaluation.rollout import evaluate_task_condition  # noqa: E402
from sb3_memret.memory.schema import MemoryEntry, MemoryType  # noqa: E402
from sb3_memret.memory.seeding import SeedingConfig  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.base import EnvFrame  # noqa: E402
from sb3_memret.tasks.mikasa.core.cue_task import DEV_SEED  # noqa: E402
from sb3_memret.tasks.mikasa.core.carry_expert import GRIP_CLOSED, GRIP_OPEN  # noqa: E402
from sb3_memret.tasks.mikasa.trace_shape.expert import path_of  # noqa: E402
from sb3_memret.tasks.mikasa.trace_shape.paths import (  # noqa: E402
    NUM_WAYPOINTS,
    SHAPES,
    TracedPath,
    fit_path,
    waypoint_fractions,
)
from sb3_memret.tasks.mikasa.trace_shape.task import (  # noqa: E402
    CUE_RELATION,
    INSTRUCTION,
    PROMPT_TEMPLATE,
    VARIANTS,
    PathWriter,
    TracePercept,
    TraceShapeTask,
    parse_path_value,
    path_value,
    red_cube_pixel,
)

TASK = "TraceShapeEasy-VLA-v0"
FORBIDDEN = ("oracle", "red", "waypoint", "checkpoint", "lamp", "visit")
SEED_OF_SHAPE = {"circle": DEV_SEED + 6, "triangle": DEV_SEED + 7, "square": DEV_SEED + 8}  # TraceShapeHard's draws


@pytest.fixture(scope="module")
def hard_env():
    env = TraceShapeTask("TraceShapeHard-VLA-v0").make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu",
                                                          robot_uids="panda")
    yield env
    env.close()


def test_the_instruction_is_mikasas(hard_env):
    assert hard_env.unwrapped.LANGUAGE_INSTRUCTION.lower().replace(". ", "; ") == INSTRUCTION


@pytest.mark.parametrize("shape", SHAPES)
def test_fit_path_recovers_mikasas_waypoints(hard_env, shape):
    """MIKASA's own waypoints of each shape: the fit names the shape, and its path's waypoints are MIKASA's to 1 mm
    (the millimetre rounding); from every other sighting alone too."""
    hard_env.reset(seed=SEED_OF_SHAPE[shape])
    waypoints = as_numpy(hard_env.unwrapped.waypoints)[0]
    assert SHAPES[int(hard_env.unwrapped.shape_type[0])] == shape
    path, residual = fit_path(waypoint_fractions(), waypoints)
    assert path.shape == shape and residual < 1e-5
    assert np.abs(path.waypoints() - waypoints).max() < 1.5e-3
    assert np.allclose(path.checkpoints(), as_numpy(hard_env.unwrapped.checkpoints)[0], atol=1.5e-3)
    half, _ = fit_path(waypoint_fractions()[::2], waypoints[::2])
    assert half == path


def test_traced_paths_round_trip_through_their_wording():
    path = TracedPath("square", (-112, 31), (-190, -40))
    assert path_value(path) == "square round -112 31 mm from -190 -40 mm"
    assert parse_path_value(path_value(path)) == path
    assert parse_path_value("hexagon round 1 2 mm from 3 4 mm") is None
    assert path.moved(0, 80) == TracedPath("square", (-112, 111), (-190, 40))
    assert np.allclose(path.waypoints()[0], (-0.190, -0.040))
    with pytest.raises(ValueError, match="unknown shape 'hexagon'"):
        TracedPath("hexagon", (0, 0), (1, 1))
    with pytest.raises(ValueError, match="at least 3 sightings"):
        fit_path(np.zeros(2), np.zeros((2, 2)))


def test_the_red_cube_is_read_from_pixels_and_placed_on_the_table(hard_env):
    """Every frame of a demonstration: the red cube's pixels cast onto the table land within 1 cm of the simulator's
    cube; once the lamp is green (the cube hidden) nothing is read."""
    task = TraceShapeTask("TraceShapeHard-VLA-v0")
    obs, _ = hard_env.reset(seed=DEV_SEED)
    errors, lamps = [], []
    for _ in range(80):
        percept = task.perceive(hard_env, obs)
        red = as_numpy(hard_env.unwrapped.red_cube.pose.p)[0]
        lamps.append(percept.lamp)
        if red[2] < 1:
            errors.append(np.hypot(percept.red_cube[0] - red[0], percept.red_cube[1] - red[1]))
        else:
            assert percept.red_cube is None
        obs, *_ = hard_env.step(np.zeros((1, 7), np.float32))
    assert max(errors) < 0.01
    assert lamps[0] is None and "red" in lamps and lamps[-1] == "green"
    with pytest.raises(ValueError, match="one \\(H, W, 3\\) frame"):
        red_cube_pixel(np.zeros((1, 128, 128, 3), np.uint8))


def test_the_writer_fits_the_demonstration_when_the_lamp_turns_green():
    """Sightings of a square at their waypoints (some hidden), then the green lamp: the square is written once."""
    path = TracedPath("square", (-100, 20), (-190, -70))
    points = path.waypoints()
    writer = PathWriter()
    assert writer.read(EnvFrame({}, {}, None, False, steps=0, percepts=[TracePercept(None, None)])) == []
    seen = [TracePercept("red", None if i % 3 == 0 else tuple(points[i])) for i in range(NUM_WAYPOINTS)]
    assert writer.read(EnvFrame({}, {}, None, False, steps=NUM_WAYPOINTS, percepts=seen)) == []
    out = writer.read(EnvFrame({}, {}, None, False, steps=2, percepts=[TracePercept("green", None)] * 2))
    assert out == [(1, {("path", "red cube"): path_value(path)})]
    assert writer.read(EnvFrame({}, {}, None, False, steps=1, percepts=[TracePercept("green", None)])) == []
    few = PathWriter()
    few.read(EnvFrame({}, {}, None, False, steps=0, percepts=[TracePercept(None, None)]))
    few.read(EnvFrame({}, {}, None, False, steps=3, percepts=[TracePercept("red", tuple(points[0]))] * 3))
    assert few.read(EnvFrame({}, {}, None, False, steps=1, percepts=[TracePercept("green", None)])) == []


def test_the_task_contract(hard_env):
    task = TraceShapeTask("TraceShapeHard-VLA-v0")
    obs, info = hard_env.reset(seed=SEED_OF_SHAPE["triangle"])
    (frame,) = task.frames(hard_env, obs, info, reset=True)
    episode = task.episode(frame)
    truth = episode.details["path"]
    assert episode.group == "triangle" == truth.shape
    (oracle,) = task.oracle_facts(episode)
    (wrong,) = task.wrong_facts(episode)
    assert path_of(parse_prompt(f"{INSTRUCTION} {oracle}", PROMPT_TEMPLATE)) == truth
    moved = path_of(parse_prompt(f"{INSTRUCTION} {wrong}", PROMPT_TEMPLATE))
    assert moved.shape == truth.shape and abs(moved.centre[1] - truth.centre[1]) == 80
    key = (MemoryType.OTHER, "red cube", CUE_RELATION)
    near = TracedPath(truth.shape, (truth.centre[0] + 4, truth.centre[1]), truth.start)
    assert episode.is_true(MemoryEntry.create(*key, path_value(near), 70))
    assert not episode.is_true(MemoryEntry.create(*key, path_value(truth.moved(0, 20)), 70))
    assert not episode.is_true(MemoryEntry.create(MemoryType.OTHER, "key", CUE_RELATION, path_value(truth), 70))
    decoys = task.seed_memories(frame, episode, np.random.default_rng(0), SeedingConfig())
    assert len(decoys) == SeedingConfig().location_decoys
    for entry in decoys:
        assert entry.entity != "red cube" and not episode.is_true(entry)
        assert path_of(parse_prompt(build_prompt(INSTRUCTION, [entry.text], PROMPT_TEMPLATE), PROMPT_TEMPLATE))
    assert task.perception_window(hard_env) == 8 + NUM_WAYPOINTS + 1


@pytest.mark.parametrize("env_id", sorted(VARIANTS))
def test_every_variant_is_registered_with_mikasas_shapes_and_length(env_id):
    from mani_skill.utils.registration import REGISTERED_ENVS
    from sb3_memret.benchmark.manifest import select_tasks

    task = make_task(env_id)
    shapes, steps = VARIANTS[env_id]
    (row,) = select_tasks(env_ids=[env_id])
    assert task.max_control_steps == steps == row.max_episode_steps
    assert task.words == shapes == tuple(SHAPES[i] for i in REGISTERED_ENVS[env_id].cls.AVAILABLE_SHAPES)


def test_an_unknown_variant_is_refused_naming_the_known_ones():
    with pytest.raises(ValueError, match="TraceShapeHardest-VLA-v0.*TraceShapeEasy-VLA-v0"):
        TraceShapeTask("TraceShapeHardest-VLA-v0")


def test_wrapper_exposes_only_the_controllers_view():
    env = make_task(TASK).make_env(obs_mode="state_dict", render_backend="cpu", sim_backend="cpu",
                                   robot_uids="panda")
    try:
        assert leaked_keys(env.unwrapped.get_obs(), FORBIDDEN)  # the raw state holds the red cube ...
        obs, _ = env.reset(seed=DEV_SEED)
        assert not leaked_keys(obs, FORBIDDEN)  # ... the controller's view does not
        assert set(obs["extra"]) == {"tcp_pose", "cube_positions", "cube_visible"}
        assert np.allclose(as_numpy(obs["extra"]["cube_positions"])[0, 0],
                           as_numpy(env.unwrapped.green_cube.pose.p)[0])
    finally:
        env.close()


@pytest.mark.parametrize("condition, succeeds", [("written", True), ("none", False), ("wrong", False)])
def test_the_path_decides_the_episode(condition, succeeds):
    """Written: the path read from the camera carries the expert round all twelve checkpoints; without one it holds
    the cube; with the path moved 8 cm it misses them."""
    (result,) = evaluate_task_condition(make_task(TASK).expert(), condition, TASK, episodes=1, seed=DEV_SEED + 1,
                                        held_out=None)
    assert result.success is succeeds


def test_the_fingers_close_only_once_the_hand_is_measured_at_the_cubes_centre():
    """A close timed on the predicted TCP pinched the cube's top edges where the arm lagged (dev seeds: the cube swung
    out of the fingers and was swept off): the fingers stay open until the TCP is at the cube's centre."""
    expert, cube = make_task(TASK).expert(), np.array([-0.3, 0.04, 0.02])
    above = expert._goal(cube + (0.0, 0.0, 0.02), cube, 0.08, None)
    assert above.mode == "grasp" and expert._grip(cube, above) == GRIP_OPEN
    assert above.point[2] < cube[2]  # aimed just below the centre: the arm stops within 8 mm of its aim
    there = expert._goal(cube + (0.004, 0.0, 0.004), cube, 0.08, None)
    assert there.mode == "seize" and expert._grip(cube, there) == GRIP_CLOSED


def test_a_low_hand_beside_the_cube_rises_before_it_moves_over():
    """Fingers low beside a dropped cube moving sideways push it away (dev seeds: off the board): up first."""
    expert, cube = make_task(TASK).expert(), np.array([-0.3, 0.04, 0.02])
    hand = cube + (0.05, 0.0, 0.01)
    waypoint = expert._waypoint(hand, expert._goal(hand, cube, 0.08, None))
    assert np.allclose(waypoint[:2], hand[:2]) and waypoint[2] > hand[2] + 0.03
