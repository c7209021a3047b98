"""MIKASA's colour-cue tasks beyond SeqOfColors3: BunchOfColors, SeqOfColors and ChainOfColors 3/5/7 and their -Long.
The variant table, the registry, a bunch read from the camera in one frame, its writer, the wrong facts of a cue that
leaves few colours out, and the expert finishing a bunch and a chain from the facts the writer wrote."""

import numpy as np
import pytest
import torch

from mikasa_support import MIKASA_MISSING

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controllers.prompts import parse_prompt  # noqa: E402
from sb3_memret.memory.schema import MemoryType  # noqa: E402
from sb3_memret.tasks import EnvFrame, make_task, task_names  # noqa: E402
from sb3_memret.tasks.mikasa.core.layout_perception import read_cue_set  # noqa: E402
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES  # noqa: E402
from sb3_memret.tasks.mikasa.seq_of_colors.task import SeqOfColorsTask  # noqa: E402
from sb3_memret.tasks.mikasa.seq_of_colors.variants import ANY_ORDER, CUE_ORDER, VARIANTS, variant  # noqa: E402
from sb3_memret.tasks.mikasa.seq_of_colors.writer import SequenceWriter, sequence_facts  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt  # noqa: E402

DEV_SEED = 5000  # development seeds only: the protocol's stay unseen


def test_the_variant_table_holds_mikasas_eighteen_ids_with_their_lengths_and_instructions():
    assert len(VARIANTS) == 18 and set(VARIANTS) <= set(task_names())
    assert variant("BunchOfColors7-Long-VLA-v0").episode_steps == 700 and variant("BunchOfColors5-VLA-v0").together
    assert [variant(f"ChainOfColors{n}-Long-VLA-v0").episode_steps for n in (3, 5, 7)] == [800, 1000, 1200]
    assert {v.episode_steps for k, v in VARIANTS.items() if "-Long" not in k} == {400}
    assert variant("ChainOfColors3-VLA-v0").instruction == CUE_ORDER != ANY_ORDER
    assert not variant("SeqOfColors7-VLA-v0").together and variant("SeqOfColors7-VLA-v0").n_items == 7
    with pytest.raises(ValueError, match="unknown colour-cue task 'SeqOfColors9-VLA-v0'; expected one of"):
        SeqOfColorsTask("SeqOfColors9-VLA-v0")


def test_each_task_takes_its_variants_length_instruction_and_prompt_contract():
    task = make_task("ChainOfColors7-Long-VLA-v0")
    assert task.max_control_steps == 1200 and task.n_items == 7 and not task.noop_before_manipulation
    assert task.instruction_text == CUE_ORDER and task.prompt_template.instructions == (CUE_ORDER,)
    episode = task.episode(EnvFrame({}, {"colours": COLOUR_NAMES[:7], "cue_step_duration": 40}, None, False))
    prompt = " ".join([task.instruction(episode), *task.oracle_facts(episode), "the red cube was touched."])
    facts = parse_prompt(prompt, task.prompt_template).facts
    assert len(facts) == 8 and dict(facts[6].fields) == {"entity": "seventh cue cube", "colour": "maroon"}
    assert task.expert().spec.prompt_template == task.prompt_template
    with pytest.raises(ValueError, match="expected one of instructions"):  # the other family's is not this one's
        parse_prompt(ANY_ORDER, task.prompt_template)


@pytest.mark.parametrize("env_id", ["SeqOfColors3-VLA-v0", "BunchOfColors7-VLA-v0"])
def test_wrong_facts_always_name_a_colour_that_was_not_cued(env_id):
    task = make_task(env_id)
    cued = COLOUR_NAMES[2:2 + task.n_items]
    episode = task.episode(EnvFrame({}, {"colours": cued, "cue_steps": 3}, None, False))
    wrong = task.wrong_facts(episode)
    named = [fact.split(" was ")[1].rstrip(".") for fact in wrong]
    assert len(wrong) == task.n_items and set(named) - set(cued) and named != list(cued)
    if task.n_items == 3:  # three of the six colours left out, in palette order
        assert named == ["red", "lime", "cyan"]


def test_a_bunch_writer_writes_every_item_at_once_in_palette_order_and_ignores_a_partial_view():
    writer = SequenceWriter(3, together=True)
    assert writer.read(EnvFrame({}, None, None, False, steps=0, percepts=[None])) == []
    partial = EnvFrame({}, None, None, False, steps=4, percepts=[("teal", "red"), None, ("teal", "red", "lime"),
                                                                 ("teal", "lime", "red")])
    assert writer.read(partial) == [(3, {("cue", "first cue cube"): "red", ("cue", "second cue cube"): "lime",
                                         ("cue", "third cue cube"): "teal"})]
    again = EnvFrame({}, None, None, False, steps=4, percepts=[("blue", "cyan", "olive")])  # written once
    assert writer.read(again) == []
    assert writer.read(EnvFrame({}, None, None, False, steps=0, percepts=[("blue", "cyan", "olive")]))[0][1] == \
        {("cue", "first cue cube"): "blue", ("cue", "second cue cube"): "cyan", ("cue", "third cue cube"): "olive"}
    with pytest.raises(ValueError, match="n_items must be in 1..8"):
        SequenceWriter(9, together=True)


def test_a_bunch_on_its_arc_is_not_taken_for_the_layout_the_touches_are_read_against():
    """The cue's three cubes stand on an arc, not where they will stand: a TCP at one of them is no touch."""
    writer = SequenceWriter(3, progress=True, together=True, read_layout=lambda seen: seen)  # the "image": a layout
    arc = {"red": np.array([0.1, -0.2]), "lime": np.array([0.15, 0.0]), "teal": np.array([0.1, 0.2])}
    obs = {"extra": {"tcp_pose": np.array([[0.1, -0.2, 0.045, 0, 1, 0, 0]])}, "sensor_data": {"base_camera": {"rgb": arc}}}
    out = writer.read(EnvFrame(obs, {}, None, False, steps=0, percepts=[("red", "lime", "teal")]))
    assert [p for _, p in out] == [{("cue", "first cue cube"): "red", ("cue", "second cue cube"): "lime",
                                    ("cue", "third cue cube"): "teal"}]
    assert writer.layout.places == {} and writer.relations["touched"] == (MemoryType.TASK_PROGRESS, "was")


@pytest.fixture(scope="module")
def bunch_env():
    task = make_task("BunchOfColors5-VLA-v0")
    env = task.make_env(obs_mode="rgb", robot_uids="panda")
    yield task, env
    env.close()


@pytest.mark.parametrize("seed", [DEV_SEED, DEV_SEED + 1])
def test_the_bunch_is_read_from_the_camera_in_each_cue_frame_and_in_no_other(bunch_env, seed):
    task, env = bunch_env
    obs, info = env.reset(seed=seed)
    base = env.unwrapped
    (frame,) = task.frames(env, obs, info, reset=True)
    truth = frame.state["colours"]
    assert len(truth) == 5 and list(truth) == sorted(truth, key=COLOUR_NAMES.index)
    cue, delay = int(base.cue_steps_per_env[0]), int(base.empty_steps_per_env[0])
    assert task.perception_window(env) == 6  # CUE_PHASE_STEPS' 5, and one more
    readings = []
    for _ in range(cue + delay + 3):
        elapsed = int(info["elapsed_steps"][0])
        seen = task.perceive(env, obs)
        readings.append((elapsed, seen))
        obs, _, _, _, info = env.step(torch.zeros(1, 7))
    for elapsed, seen in readings:
        if elapsed < cue:
            assert seen is not None and sorted(seen, key=COLOUR_NAMES.index) == list(truth), (elapsed, seen)
        else:
            assert seen is None, (elapsed, seen)  # the empty table, then all nine cubes
    rgb = obs["sensor_data"]["base_camera"]["rgb"][0].numpy()
    assert read_cue_set(rgb, 9) is None


@pytest.mark.parametrize("env_id", ["BunchOfColors5-VLA-v0", "ChainOfColors5-VLA-v0"])
def test_the_stateless_expert_finishes_from_the_facts_the_writer_wrote(env_id):
    """Development seed 5000: the cue's five facts and the progress, all written from the camera and the arm's
    sensors, carry the stateless expert to MIKASA's success."""
    from sb3_memret.evaluation.rollout import condition_schedule, play_task_episodes

    task = make_task(env_id)
    [written] = play_task_episodes(task.expert(), task, [DEV_SEED], condition_schedule(task, "written"),
                                   render_backend="cpu")
    assert written.success, written


def test_in_mikasas_harness_the_progress_writer_reads_images_rendered_for_each_decision():
    """BunchOfColors3, development seed 5003: its cubes come out after the writer's perception window (the cue's 6
    steps), and the scripted controller reads no images; the progress writer's layout must still come from images
    rendered at each decision (``Task.frames_read_images``), else it reads the empty table for the whole episode and
    writes no touch."""
    from sb3_memret.benchmark import harness
    from sb3_memret.benchmark.agent import MemoryAgent

    task = make_task("BunchOfColors3-VLA-v0")
    assert task.frames_read_images and not SeqOfColorsTask("BunchOfColors3-VLA-v0", progress=False).frames_read_images
    env = harness.make_env(task.name)
    try:
        agent = MemoryAgent(task, task.expert(), "written", task.replan_every)
        agent.bind(env)
        base = env.unwrapped
        agent.begin(0)
        result = harness.play_episode(env, agent, DEV_SEED + 3)
        assert int(base.cue_steps_per_env[0] + base.empty_steps_per_env[0]) > task.perception_window(env)
    finally:
        env.close()
    assert result.success_once and any("the button was pressed." in prompt for prompt in agent.prompts)


def test_leaving_a_touched_cube_the_hand_rises_before_it_heads_sideways():
    """The fingertips rest on a touched cube's top: heading sideways from there drags it (MIKASA fails a cube pushed
    6 cm), so the expert first lifts the TCP straight up, then crosses the table."""
    from test_mikasa_seq import _synthetic_obs  # red at y = -0.3, teal at +0.3

    from sb3_memret.tasks.mikasa.seq_of_colors.task import PROGRESS_PROMPT_TEMPLATE, sequence_expert

    expert, obs = sequence_expert(progress_from="prompt"), _synthetic_obs(1)
    expert.reset([1])
    at_red = {**obs, "extra": {**obs["extra"], "tcp_pose": np.array([[0.0, -0.3, 0.046, 0, 1, 0, 0]])}}
    prompt = build_prompt(ANY_ORDER, [*sequence_facts(("red", "teal")), "the red cube was touched."],
                          PROGRESS_PROMPT_TEMPLATE)
    chunk = expert.act(at_red, [prompt])[0]
    assert chunk[0, 2] > 0 and np.abs(chunk[0, :2]).max() < 0.25 * chunk[0, 2]  # up, hardly sideways
    high = {**obs, "extra": {**obs["extra"], "tcp_pose": np.array([[0.0, -0.3, 0.12, 0, 1, 0, 0]])}}
    assert expert.act(high, [prompt])[0][0, 1] > 0.1  # clear of the cubes: straight for teal
