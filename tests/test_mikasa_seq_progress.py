"""Progress as memory on MIKASA's SeqOfColors3: the cube layout read from the base camera, the writer's touch and
press facts, and the stateless expert that learns what it has done from them alone."""

import numpy as np
import pytest
import torch

from mikasa_support import MIKASA_MISSING

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.memory.schema import MemoryType  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt, parse_prompt  # noqa: E402
from sb3_memret.tasks import EnvFrame, make_task  # noqa: E402
from sb3_memret.tasks.mikasa.core.layout_perception import name_blobs, read_cube_layout, table_points  # noqa: E402
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES, _palette  # noqa: E402
from sb3_memret.tasks.mikasa.seq_of_colors.task import (  # noqa: E402
    EPISODE_STEPS,
    INSTRUCTION,
    PROGRESS_PROMPT_TEMPLATE,
    SeqOfColorsTask,
    SequenceWriter,
    sequence_expert,
    sequence_facts,
)
from sb3_memret.tasks.mikasa.core.sequence_expert import prompt_progress  # noqa: E402

SPEC = "SeqOfColors3-VLA-v0"  # progress as memory: the registered task
DEV_SEED = 5000  # cyan, maroon, olive (a development seed: the protocol's stay unseen)


def test_table_points_cast_pixels_onto_the_plane():
    """A camera 1 m above the origin looking straight down (focal 100 px, centre (64, 64)): pixel (row, col) sees
    the table point ((64 - row) / 100, (64 - col) / 100) scaled by its height over the plane."""
    intrinsic = np.array([[100.0, 0, 64], [0, 100.0, 64], [0, 0, 1]])
    rotation = np.array([[0.0, -1, 0], [-1, 0, 0], [0, 0, -1]])  # camera x = -world y, y = -world x, z = down
    extrinsic = np.column_stack([rotation, -rotation @ np.array([0.0, 0, 1])])
    points = table_points(np.array([[64.0, 64.0], [54.0, 84.0]]), intrinsic, extrinsic, plane_z=0.2)
    assert np.allclose(points, [[0, 0], [0.08, -0.16]])
    level = np.array([[0.0, 1, 0], [0, 0, -1], [1, 0, 0]])  # looking along world x: the centre ray never dips
    extrinsic = np.column_stack([level, -level @ np.array([0.0, 0, 1])])
    assert np.isnan(table_points(np.array([[64.0, 64.0]]), intrinsic, extrinsic, plane_z=0.0)).all()
    with pytest.raises(ValueError, match="n_colours must be in 1..9"):
        read_cube_layout(np.zeros((8, 8, 3), np.uint8), intrinsic, extrinsic, 10)


def test_cubes_touching_in_the_image_are_split_by_colour_and_a_shaded_face_does_not_split_a_cube():
    shades, owner = _palette(9)
    top = {COLOUR_NAMES[int(i)]: shades[2 * int(i)] for i in range(9)}  # each colour's top-face shade
    rgb = np.zeros((128, 128, 3), np.uint8)  # the base camera's size: the pixel thresholds are set for it
    rgb[10:15, 10:15], rgb[10:15, 15:20] = top["red"], top["lime"]  # two cubes side by side: one blob
    rgb[30:35, 30:35], rgb[34, 30:34] = top["maroon"], top["red"]  # a maroon cube, four pixels shaded toward red
    blobs = name_blobs(rgb, 9)
    assert sorted(blobs) == ["lime", "maroon", "red"]
    assert np.allclose(blobs["red"], [12.5, 12.5]) and np.allclose(blobs["lime"], [12.5, 17.5])
    assert np.allclose(blobs["maroon"], [32.5, 32.5])
    rgb[40:45, 40:45] = top["red"]  # red seen twice: not placed
    assert "red" not in name_blobs(rgb, 9)


@pytest.mark.parametrize("seed", [DEV_SEED, DEV_SEED + 1])  # 5001: a maroon cube whose faces vote 19 to 5 red
def test_the_layout_is_read_from_the_base_camera_within_a_centimetre(seed):
    task = SeqOfColorsTask()
    env = task.make_env(obs_mode="rgb", robot_uids="panda")
    try:
        obs, _ = env.reset(seed=seed)
        for _ in range(25):  # cue (3 items of 1-5 steps) and delay: into the manipulation phase
            obs, *_ = env.step(torch.zeros(1, 7))
        params = env.unwrapped.get_sensor_params()["base_camera"]
        layout = read_cube_layout(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0],
                                  as_numpy(params["intrinsic_cv"])[0], as_numpy(params["extrinsic_cv"])[0], 9)
        truth = as_numpy(obs["extra"]["cube_positions"])[0]
        assert sorted(layout) == sorted(COLOUR_NAMES)
        errors = {c: float(np.linalg.norm(p - truth[COLOUR_NAMES.index(c), :2])) for c, p in layout.items()}
        assert max(errors.values()) < 0.008, errors
    finally:
        env.close()


def _layout() -> dict[str, np.ndarray]:
    """Nine cubes on an arc; their mean is at x = -0.06, so the button stands at (-0.10, 0)."""
    return {c: np.array([-0.06 + 0.1 * np.cos(a), 0.3 * np.sin(a)]) - (0.1 * np.cos(np.linspace(-1, 1, 9)).mean(), 0)
            for c, a in zip(COLOUR_NAMES, np.linspace(-1, 1, 9))}


def _frame(tcp, steps: int = 4, seen=None, percepts=()) -> EnvFrame:
    """The hand's pose, as the harness gives it, and for the base camera's "image" the layout it shows (the writers
    under test read it with ``read_layout=_seen``)."""
    obs = {"extra": {"tcp_pose": np.array([[*tcp, 0, 1, 0, 0]])},
           "sensor_data": {"base_camera": {"rgb": _layout() if seen is None else seen}}}
    return EnvFrame(obs, {}, None, False, steps=steps, percepts=list(percepts))


def _seen(layout):
    return layout


def test_the_writer_writes_each_touch_and_the_press_once_from_what_it_saw():
    writer, layout = SequenceWriter(3, progress=True, read_layout=_seen), _layout()
    assert writer.relations["touched"] == writer.relations["pressed"] == (MemoryType.TASK_PROGRESS, "was")
    red = (*layout["red"], 0.045)
    cue_only = {"red": np.array([0.0, 0.0])}  # the cue at the table centre: never where the red cube will stand
    assert writer.read(_frame((0.0, 0.0, 0.045), steps=0, seen=cue_only, percepts=["red"])) == \
        [(0, {("cue", "first cue cube"): "red"})]
    assert writer.read(_frame(red)) == []  # arriving over it (8 cm since the last frame): not a touch yet
    assert writer.read(_frame((red[0], red[1] + 0.005, red[2]))) == []  # still moving 1.25 mm a step
    assert writer.read(_frame((red[0], red[1] + 0.005, red[2]))) == [(4, {("touched", "red cube"): "touched"})]
    assert writer.read(_frame(red)) == []  # once
    assert writer.read(_frame((*layout["red"], 0.09))) == []  # 4.5 cm over the touch point
    button = np.mean(list(layout.values()), axis=0) - (0.04, 0)
    assert writer.read(_frame((*button, 0.09))) == []  # over the cap, not down on it
    assert writer.read(_frame((*button, 0.07))) == []  # on its way down
    assert writer.read(_frame((*button, 0.07))) == [(4, {("pressed", "button"): "pressed"})]
    assert writer.read(_frame((*button, 0.07), steps=0, seen={})) == []  # a new episode starts afresh
    assert writer.read(_frame(red, seen={"red": layout["red"]})) == []  # one cube in sight is the cue's
    with pytest.raises(ValueError, match="sensor_data/base_camera/rgb"):
        writer.read(EnvFrame({"extra": {}}, None, None, False, steps=4))


def test_progress_facts_are_worded_for_the_prompt_and_read_back_by_the_stateless_expert():
    task = make_task(SPEC)
    assert task.progress and task.prompt_template == PROGRESS_PROMPT_TEMPLATE
    from sb3_memret.memory.schema import linearize

    touched = linearize(MemoryType.TASK_PROGRESS, "red cube", "was", "touched", task.wordings)
    pressed = linearize(MemoryType.TASK_PROGRESS, "button", "was", "pressed", task.wordings)
    assert (touched, pressed) == ("the red cube was touched.", "the button was pressed.")
    prompt = build_prompt(INSTRUCTION, [*sequence_facts(("red", "teal", "lime")), touched, pressed],
                          task.prompt_template)
    progress = prompt_progress(parse_prompt(prompt, task.prompt_template))
    assert progress.touched == ["red"] and progress.pressed
    expert = task.expert()
    assert not expert.stateful and expert.progress_from == "prompt"
    with pytest.raises(ValueError, match="unknown progress_from 'memory'"):
        sequence_expert(progress_from="memory")
    from sb3_memret.tasks.mikasa.seq_of_colors.task import PROMPT_TEMPLATE
    from sb3_memret.tasks.mikasa.core.sequence_expert import SequenceTouchController

    with pytest.raises(ValueError, match="needs the progress facts"):
        SequenceTouchController(PROMPT_TEMPLATE, progress_from="prompt")


def test_the_stateless_expert_heads_for_the_first_cube_its_prompt_does_not_call_touched():
    from test_mikasa_seq import _synthetic_obs  # red at y = -0.3, lime at -0.225, teal at +0.3

    expert, obs = sequence_expert(progress_from="prompt"), _synthetic_obs(2)
    expert.reset([1, 2])
    facts = sequence_facts(("red", "teal", "lime"))
    at_red = {**obs, "extra": {**obs["extra"], "tcp_pose": np.tile([0.0, -0.3, 0.046, 0, 1, 0, 0], (2, 1))}}
    prompts = [build_prompt(INSTRUCTION, facts, PROGRESS_PROMPT_TEMPLATE),
               build_prompt(INSTRUCTION, [*facts, "the red cube was touched."], PROGRESS_PROMPT_TEMPLATE)]
    for _ in range(2):  # holding still on red's touch point changes nothing until the prompt says so
        chunks = expert.act(at_red, prompts)
        assert np.abs(chunks[0, :, :3]).max() < 0.05 and chunks[1, 0, 2] > 0  # stays; leaves upwards for teal
    assert expert.progress == [] or all(not p.touched for p in expert.progress)  # it keeps nothing itself


class CueFactsOnly:
    """The cue's true facts and nothing of the progress: the oracle as it was before it stated what was done."""

    def __init__(self, task):
        self.task, self._facts = task, []

    def start(self, frame, episode):
        self._facts = self.task.oracle_facts(episode)

    def observe(self, frame):
        pass

    def facts(self, decision):
        return self._facts


@pytest.mark.slow
def test_written_or_simulated_progress_lets_the_stateless_expert_finish_and_cue_facts_alone_do_not(monkeypatch):
    """Development seed 5000: with the facts the writer wrote (the cue and, as it goes, the touches and the press)
    the stateless expert succeeds, and with the oracle (the cue's facts and the progress MIKASA counted) too; with
    the cue's facts alone it never leaves the first cube."""
    from sb3_memret.evaluation.rollout import condition_schedule, play_task_episodes

    task = make_task(SPEC)
    monkeypatch.setattr(task, "max_control_steps", 104)  # the writer waits for the hand to settle
    done = ["the cyan cube was touched.", "the maroon cube was touched.", "the olive cube was touched.",
            "the button was pressed."]
    for condition in ("written", "oracle"):
        facts: list[list[str]] = []
        schedule = condition_schedule(task, condition)
        original = schedule.facts
        monkeypatch.setattr(schedule, "facts", lambda decision: facts.append(list(original(decision))) or facts[-1])
        [played] = play_task_episodes(task.expert(), task, [DEV_SEED], schedule, render_backend="cpu")
        assert played.success and facts[-1][3:] == done, (condition, facts[-1])
    [cue_only] = play_task_episodes(task.expert(), task, [DEV_SEED], CueFactsOnly(task), render_backend="cpu")
    assert not cue_only.success


@pytest.mark.slow
def test_demonstrations_carry_the_progress_written_so_far_in_each_decisions_prompt():
    """A recorded episode's prompts change as the writer writes what was done: the first has the cue facts alone,
    later ones add each touch in turn, so a controller finetuned on them learns to read its progress."""
    from sb3_memret.stage1.demos import DemoRecorder
    from sb3_memret.tasks.demos import DemoEpisode

    recorder = DemoRecorder(make_task(SPEC), "cpu", frames="decisions")
    try:
        recorded = recorder.record(DemoEpisode(DEV_SEED, "matching"))
    finally:
        recorder.env.close()
    assert recorded.success and len(recorded.prompts) == len(recorded.frames) == len(recorded.frame_steps)
    assert len(recorded.actions) < EPISODE_STEPS  # it ends at success, as the decision env's episodes do
    cue = " ".join(sequence_facts(("cyan", "maroon", "olive")))
    assert recorded.prompts[0] == recorded.prompt == f"{INSTRUCTION} {cue}"
    touched = [f"the {c} cube was touched." for c in ("cyan", "maroon", "olive")]
    seen = [tuple(t for t in touched if t in p) for p in recorded.prompts]
    assert seen[-1] == tuple(touched) and seen == sorted(seen, key=len)  # added one by one, never taken back
