"""MIKASA TraceShapeSeq: the sequence fact and its wording, the progress fact, the reader beside the button, the writer
(sequence and progress), the sequence expert's plan, the task contract, one written episode end to end. Development
seeds (5000+) only."""

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
from sb3_memret.tasks.mikasa.trace_shape.sequence_expert import (  # noqa: E402
    ARM_BASE_XY,
    paths_done,
    sequence_of,
    within_reach,
)
from sb3_memret.tasks.mikasa.trace_shape.paths import NUM_WAYPOINTS, TracedPath  # noqa: E402
from sb3_memret.tasks.mikasa.trace_shape.sequence import (  # noqa: E402
    INSTRUCTION,
    PROMPT_TEMPLATE,
    VARIANTS,
    PathSequenceWriter,
    SeqPercept,
    TraceShapeSeqTask,
    parse_sequence_value,
    red_cube_pixel_beside_button,
    sequence_fact,
    sequence_value,
)
from sb3_memret.tasks.mikasa.trace_shape.task import red_cube_pixel  # noqa: E402

TASK = "TraceShapeSeqEasy-VLA-v0"
TWO_PATHS_SEED = DEV_SEED + 4  # TraceShapeSeqEasy draws two paths there
PATHS = [TracedPath("circle", (-65, 73), (3, -17)), TracedPath("square", (-65, 73), (-149, 41))]


def _frame(steps, percepts):
    return EnvFrame({}, {}, None, False, steps=steps, percepts=list(percepts))


def test_the_instruction_is_mikasas():
    from mani_skill.utils.registration import REGISTERED_ENVS

    stated = REGISTERED_ENVS[TASK].cls.LANGUAGE_INSTRUCTION.lower().replace(". ", "; ")
    assert stated == INSTRUCTION


def test_a_sequence_is_one_fact_and_reads_back():
    fact = sequence_fact(PATHS)
    assert fact == "the red cube traced round -65 73 mm, a circle from 3 -17 mm, then a square from -149 41 mm."
    parsed = parse_prompt(build_prompt(INSTRUCTION, [fact, "the green cube traced one path."], PROMPT_TEMPLATE),
                          PROMPT_TEMPLATE)
    assert sequence_of(parsed) == PATHS and paths_done(parsed) == 1
    assert paths_done(parse_prompt(f"{INSTRUCTION} {fact}", PROMPT_TEMPLATE)) == 0
    assert parse_sequence_value(sequence_value(PATHS)) == PATHS
    assert parse_sequence_value("round 1 2 mm, a hexagon from 3 4 mm") is None
    five = [TracedPath("triangle", (0, 0), (i, -i)) for i in range(5)]
    assert sequence_of(parse_prompt(f"{INSTRUCTION} {sequence_fact(five)}", PROMPT_TEMPLATE)) == five
    with pytest.raises(ValueError, match="2-5 paths round one centre"):
        sequence_value(PATHS[:1])
    with pytest.raises(ValueError, match="2-5 paths round one centre"):
        sequence_value([PATHS[0], PATHS[1].moved(1, 0)])


def test_the_writer_reads_the_sequence_then_counts_the_paths_closed():
    writer = PathSequenceWriter()
    held, tcp0 = 0.036, (0.0, 0.0)
    assert writer.read(_frame(0, [SeqPercept(None, None, tcp0, 0.08)])) == []
    demo = [SeqPercept("red", tuple(PATHS[k // NUM_WAYPOINTS].waypoints()[k % NUM_WAYPOINTS]), tcp0, held)
            for k in range(2 * NUM_WAYPOINTS)]
    assert writer.read(_frame(len(demo), demo)) == []
    (step, cue), = writer.read(_frame(1, [SeqPercept("green", None, tcp0, held)]))
    assert cue == {("sequence", "red cube"): sequence_value(PATHS)}
    loop = [SeqPercept("green", None, tuple(p), held) for p in PATHS[0].waypoints()[:56]]
    assert writer.read(_frame(len(loop), loop)) == []  # every checkpoint (the last is waypoint 55), not back yet
    out = writer.read(_frame(1, [SeqPercept("green", None, tuple(PATHS[0].waypoints()[0]), held)]))
    assert out == [(1, {("progress", "green cube"): "one path"})]
    loose = [SeqPercept("green", None, tuple(p), 0.08) for p in [*PATHS[1].waypoints(), PATHS[1].waypoints()[0]]]
    assert writer.read(_frame(len(loose), loose)) == []  # the fingers hold nothing: not the cube's path
    again = [SeqPercept("green", None, tuple(p), held) for p in [*PATHS[1].waypoints(), PATHS[1].waypoints()[0]]]
    assert writer.read(_frame(len(again), again))[-1][1] == {("progress", "green cube"): "two paths"}


def test_the_reader_leaves_the_button_out():
    """At a reset the frame shows the red cube and the button's pink cap: the cap pulls the plain reader off the cube,
    the reader beside the button does not."""
    from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC

    task = make_task(TASK)
    env = task.make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    try:
        obs, _ = env.reset(seed=TWO_PATHS_SEED)
        rgb = as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0]
        cube = as_numpy(env.unwrapped.red_cube.pose.p)[0]
        camera = BASE_CAMERA_EXTRINSIC[:, :3] @ cube + BASE_CAMERA_EXTRINSIC[:, 3]
        col, row = (BASE_CAMERA_INTRINSIC @ camera)[:2] / camera[2]
        assert np.hypot(*(red_cube_pixel_beside_button(rgb) - (row, col))) < 3
        assert np.hypot(*(red_cube_pixel(rgb) - (row, col))) > 5
        percept = task.perceive(env, obs)
        assert np.hypot(percept.red_cube[0] - cube[0], percept.red_cube[1] - cube[1]) < 0.01
    finally:
        env.close()


def test_the_task_contract():
    task = make_task(TASK)
    env = task.make_env(obs_mode="state_dict", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    try:
        obs, info = env.reset(seed=TWO_PATHS_SEED)
        assert not leaked_keys(obs, ("oracle", "red", "waypoint", "checkpoint", "lamp", "closed", "sequence"))
        assert set(obs["extra"]) == {"tcp_pose", "cube_positions", "cube_visible", "button_position"}
        (frame,) = task.frames(env, obs, info, reset=True)
    finally:
        env.close()
    episode = task.episode(frame)
    paths = episode.details["paths"]
    assert episode.group == "2 paths" and len({p.centre for p in paths}) == 1
    (oracle,) = task.oracle_facts(episode)
    (wrong,) = task.wrong_facts(episode)
    assert sequence_of(parse_prompt(f"{INSTRUCTION} {oracle}", PROMPT_TEMPLATE)) == paths
    moved = sequence_of(parse_prompt(f"{INSTRUCTION} {wrong}", PROMPT_TEMPLATE))
    assert [p.shape for p in moved] == [p.shape for p in paths] and abs(moved[0].centre[1] - paths[0].centre[1]) == 80
    assert task.progress_facts(frame) == []
    assert task.progress_facts(EnvFrame({}, {"paths": paths, "closed": 2}, None, False)) == \
        ["the green cube traced two paths."]
    key = (MemoryType.OTHER, "red cube", "traced")
    assert episode.is_true(MemoryEntry.create(*key, sequence_value(paths), 200))
    assert not episode.is_true(MemoryEntry.create(*key, sequence_value([p.moved(0, 30) for p in paths]), 200))
    for entry in task.seed_memories(frame, episode, np.random.default_rng(0), SeedingConfig()):
        assert not episode.is_true(entry) and sequence_of(parse_prompt(f"{INSTRUCTION} {entry.text}", PROMPT_TEMPLATE))


@pytest.mark.parametrize("env_id", sorted(VARIANTS))
def test_every_variant_is_registered_with_mikasas_shapes_and_length(env_id):
    from mani_skill.utils.registration import REGISTERED_ENVS
    from sb3_memret.benchmark.manifest import select_tasks
    from sb3_memret.tasks.mikasa.trace_shape.paths import SHAPES

    task = make_task(env_id)
    (row,) = select_tasks(env_ids=[env_id])
    assert task.max_control_steps == VARIANTS[env_id][1] == row.max_episode_steps
    assert task.words == tuple(SHAPES[i] for i in REGISTERED_ENVS[env_id].cls.AVAILABLE_SHAPES)
    with pytest.raises(ValueError, match="unknown TraceShapeSeq task"):
        TraceShapeSeqTask(env_id.replace("Seq", "Sequence"))


@pytest.mark.slow
def test_the_written_sequence_and_progress_carry_the_expert_to_the_button():
    """The writer's sequence from the camera and its progress from the arm: both paths traced in order, then the
    button; without facts, nothing is submitted."""
    (written,) = evaluate_task_condition(make_task(TASK).expert(), "written", TASK, episodes=1, seed=TWO_PATHS_SEED,
                                         held_out=None)
    assert written.success


def test_the_press_never_commands_a_point_beyond_the_arms_reach():
    """pd_ee_delta_pose keeps the joints where its IK fails: a press commanding a point beyond reach froze the arm by
    a far button for hundreds of steps (dev seeds). Each step's commanded point is cut back to the reach; a chunk
    within reach is left alone."""
    base = np.asarray(ARM_BASE_XY)
    pos, still = np.array([0.13, 0.2, 0.08]), np.zeros(3)
    out = np.zeros((4, 7))
    out[:, 0], out[:, 1] = 1.0, 0.3
    cut = within_reach(out, pos, still, 0.80)
    assert np.linalg.norm(pos[:2] + 0.1 * cut[0, :2] - base) == pytest.approx(0.80)
    assert (cut[:, 2:] == out[:, 2:]).all()
    near = np.zeros((4, 7))
    near[:, 0] = -0.5
    assert np.array_equal(within_reach(near, pos, still, 0.80), near)
