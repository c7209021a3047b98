"""Progress as memory on MIKASA's BlinkCountButtonPress: the red cap read from the base camera, the writer's press
fact counted as MIKASA counts, and the stateless expert that learns how often it pressed from that fact alone."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.memory.schema import MemoryType, linearize  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt, parse_prompt  # noqa: E402
from sb3_memret.tasks import EnvFrame, make_task  # noqa: E402
from sb3_memret.tasks.mikasa.blink_count.task import (  # noqa: E402
    CAP_TOP_Z,
    CUE_FACT,
    INSTRUCTION,
    PROGRESS_PROMPT_TEMPLATE,
    PROMPT_TEMPLATE,
    BlinkCountTask,
    BlinkWriter,
    PressPercept,
    read_red_cap,
)
from sb3_memret.tasks.mikasa.blink_count.expert import ButtonPressController, count_value, stated_presses  # noqa: E402

SPEC = "BlinkCountButtonPressMedium-VLA-v0"  # progress as memory: the registered task
DEV_SEED = 5000  # development seeds: the protocol's stay unseen
CAP = (-0.1, 0.0)


@pytest.mark.parametrize("seed", [6000, 6003])
def test_the_red_cap_is_read_from_the_base_camera_within_half_a_centimetre(seed):
    task = BlinkCountTask("BlinkCountButtonPressMedium-VLA-v0")
    env = task.make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    try:
        obs, _ = env.reset(seed=seed)
        percept = task.perceive(env, obs)
        truth = as_numpy(env.unwrapped.button_base.pose.p)[0, :2]
        tcp = as_numpy(obs["extra"]["tcp_pose"])[0, :3]
    finally:
        env.close()
    assert isinstance(percept, PressPercept) and percept.red_cap is not None
    assert np.linalg.norm(np.array(percept.red_cap) - truth) < 0.005
    assert np.allclose(percept.tcp, tcp) and not percept.green  # the cue: the phase lamp is red


def test_no_cap_in_sight_reads_none_and_a_bad_frame_is_refused():
    intrinsic = np.array([[100.0, 0, 64], [0, 100.0, 64], [0, 0, 1]])
    extrinsic = np.hstack([np.eye(3), [[0.0], [0.0], [1.0]]])
    assert read_red_cap(np.zeros((128, 128, 3), np.uint8), intrinsic, extrinsic) is None
    tiny = np.zeros((128, 128, 3), np.uint8)
    tiny[10:12, 10:12] = (211, 136, 136)  # 4 pixels: too few for a cap
    assert read_red_cap(tiny, intrinsic, extrinsic) is None
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        read_red_cap(np.zeros((128, 128)), intrinsic, extrinsic)


def _percepts(heights, green=True, xy=CAP, cap=CAP):
    """One PressPercept per TCP height (m over the cap's top)."""
    return [PressPercept(False, green, (xy[0], xy[1], CAP_TOP_Z + h), cap) for h in heights]


def _read(writer, percepts, steps=None):
    frame = EnvFrame({}, None, None, False, steps=len(percepts) if steps is None else steps, percepts=percepts)
    return writer.read(frame)


def test_the_writer_counts_a_press_once_it_is_lifted_as_mikasa_counts_it():
    writer = BlinkWriter(progress=True)
    assert writer.relations["pressed"] == (MemoryType.TASK_PROGRESS, "pressed")
    assert _read(writer, _percepts([0.13]), steps=0) == []  # the reset frame
    assert _read(writer, _percepts([0.13, 0.01, 0.01, 0.13], green=False)) == []  # the cue: no press counts
    down_up = [0.10, 0.05, 0.01, 0.05, 0.09, 0.13]  # started 1 cm over the top: counts at 9.5 cm
    assert _read(writer, _percepts(down_up)) == [(6, {("pressed", "red button"): "once"})]
    assert _read(writer, _percepts([0.13, 0.024, 0.06, 0.11])) == [(4, {("pressed", "red button"): "twice"})]
    assert _read(writer, _percepts([0.03, 0.026, 0.13])) == []  # not down to 2.51 cm over the top: no press
    assert _read(writer, _percepts(down_up, xy=(-0.1, 0.16))) == []  # the black button
    assert _read(writer, _percepts([0.01, 0.05])) == []  # pressed, not lifted yet ...
    assert _read(writer, _percepts([0.0951])) == [(1, {("pressed", "red button"): "three times"})]  # ... now
    assert _read(writer, _percepts([0.13]), steps=0) == []  # a new episode starts afresh ...
    assert _read(writer, _percepts(down_up)) == [(6, {("pressed", "red button"): "once"})]  # ... counting from one
    with pytest.raises(ValueError, match="PressPercept"):
        _read(writer, [(False, True)])


def test_the_writer_waits_for_the_cap_to_be_seen_and_keeps_its_first_sighting():
    writer = BlinkWriter(progress=True)
    _read(writer, _percepts([0.13], cap=None), steps=0)
    assert _read(writer, _percepts([0.01, 0.13], cap=None)) == []  # nowhere to count against yet
    assert _read(writer, _percepts([0.13], cap=CAP)) == []
    later = (0.3, 0.3)  # a later misreading (the arm over the cap) changes nothing
    assert _read(writer, _percepts([0.01, 0.13], cap=later)) == [(2, {("pressed", "red button"): "once"})]


def test_progress_facts_are_worded_for_the_prompt_and_read_back_by_the_stateless_expert():
    task = make_task(SPEC)
    assert task.progress and task.prompt_template == PROGRESS_PROMPT_TEMPLATE
    assert task.perception_window(None) is None  # every press is read, the whole episode
    fact = linearize(MemoryType.TASK_PROGRESS, "red button", "pressed", "twice", task.wordings)
    assert fact == "the red button was pressed twice."
    prompt = build_prompt(INSTRUCTION, [CUE_FACT.format(count="four times"), fact], task.prompt_template)
    parsed = parse_prompt(prompt, task.prompt_template)
    expert = task.expert()
    assert stated_presses(parsed) == 2 and expert.count_of(parsed) == 4  # the cue's count is not the presses'
    assert not expert.stateful and expert.progress_from == "prompt"
    assert stated_presses(parse_prompt(INSTRUCTION, task.prompt_template)) == 0
    with pytest.raises(ValueError, match="unknown progress_from 'memory'"):
        ButtonPressController(PROGRESS_PROMPT_TEMPLATE, progress_from="memory")
    with pytest.raises(ValueError, match="needs the progress fact"):
        ButtonPressController(PROMPT_TEMPLATE, progress_from="prompt")
    assert BlinkCountTask("BlinkCountButtonPressMedium-VLA-v0", progress=False).expert().stateful  # counts itself


def _obs(height: float, qvel_z: float, green: bool = True) -> dict:
    """One env, the TCP ``height`` over the red cap's top, the arm's joints moving so the TCP rises at about
    ``qvel_z`` (joint 2 of the Panda's ready pose lifts the hand when it turns negative)."""
    qpos = np.array([[0, 0, 0, -2.09, 0, 2.09, 0.79, 0.0, 0.0]])
    qvel = np.zeros((1, 9))
    qvel[0, 3] = qvel_z * 4  # the elbow: a positive speed raises the hand at this pose
    red, black = [*CAP, 0.015], [CAP[0], CAP[1] + 0.16, 0.015]
    return {"agent": {"qpos": qpos, "qvel": qvel},
            "extra": {"tcp_pose": np.array([[*CAP, CAP_TOP_Z + height, 0, 1, 0, 0]]),
                      "button_positions": np.array([[red, black]]), "button_visible": np.ones((1, 2), bool),
                      "lamp_green": np.array([green])}}


def test_the_stateless_expert_reads_its_way_from_where_the_hand_is_and_how_it_moves():
    from sb3_memret.tasks.mikasa.core.touch_expert import tcp_velocity

    task = make_task(SPEC)
    expert = task.expert()
    expert.reset([1])
    cue = CUE_FACT.format(count="twice")
    prompt = build_prompt(INSTRUCTION, [cue], task.prompt_template)
    done = build_prompt(INSTRUCTION, [cue, "the red button was pressed twice."], task.prompt_template)
    rising = tcp_velocity(_obs(0.06, 0.1)["agent"]["qpos"], _obs(0.06, 0.1)["agent"]["qvel"])[0, 2]
    assert rising > 0.05  # the helper's joints do raise the hand

    def first_z(obs, p=prompt):
        return expert.act(obs, [p])[0, 0, 2]

    assert first_z(_obs(0.13, 0.0, green=False)) == pytest.approx(0.0, abs=1e-3)  # the cue: it waits at the top
    assert first_z(_obs(0.13, 0.0)) < 0  # the top of a lift, presses to make: down
    assert first_z(_obs(0.005, 0.0)) > 0  # pressed: up
    assert first_z(_obs(0.06, 0.1)) > 0  # on the way up: on up
    assert first_z(_obs(0.06, -0.1)) < 0  # on the way down: on down
    assert first_z(_obs(0.06, 0.0)) > 0  # standing in between: up, which never adds a press
    sideways = expert.act(_obs(0.13, 0.0), [done])[0, 0, 1]
    assert sideways > 0  # both presses made: over to the black button (16 cm to the left)


def test_every_fixed_condition_states_the_presses_mikasa_counted():
    from sb3_memret.evaluation.rollout import condition_schedule

    task, base = make_task(SPEC), BlinkCountTask("BlinkCountButtonPressMedium-VLA-v0", progress=False)
    start, later = ({"blinks": 3, "presses": n} for n in (0, 2))
    frame = EnvFrame({}, start, None, False)
    episode = task.episode(frame)
    assert task.progress_facts(frame) == [] and base.progress_facts(EnvFrame({}, later, None, False)) == []
    pressed = "the red button was pressed twice."
    expected = {"oracle": [CUE_FACT.format(count="three times")], "wrong": [CUE_FACT.format(count="four times")],
                "none": []}
    for condition, cue in expected.items():
        schedule = condition_schedule(task, condition)
        schedule.start(frame, episode)
        assert list(schedule.facts(0)) == cue
        schedule.observe(EnvFrame({}, later, None, False, steps=4))
        assert list(schedule.facts(1)) == [*cue, pressed]
        build_prompt(INSTRUCTION, schedule.facts(1), task.prompt_template)  # the contract reads it


def test_recall_keeps_progress_beside_the_bank_and_states_it_after_the_chosen_facts(encoder):
    """The bank holds what may be recalled (the cue, the decoys); the presses written so far follow whatever the
    retriever chose, in every mode, the latest count replacing the last, and a new episode starts with none."""
    from sb3_memret.envs.configs import MemoryConfig
    from sb3_memret.envs.recall_memory import EpisodeMemory

    task = make_task(SPEC)
    modes = {mode: EpisodeMemory(MemoryConfig(4), mode, encoder, lambda entries, ages, timescale: np.ones(len(entries)),
                                 task.prompt_template, task) for mode in ("recall", "oracle", "none")}
    down_up = [0.10, 0.05, 0.01, 0.05, 0.09, 0.13]
    cue = CUE_FACT.format(count="three times")
    for mode, memory in modes.items():
        memory.start(EnvFrame({}, {"blinks": 3}, None, False, steps=0, percepts=_percepts([0.13])),
                     np.random.default_rng(0))
        chosen = memory.choose(np.array([0]))  # a decoy
        for presses in ("once", "twice"):
            memory.observe(EnvFrame({}, {"blinks": 3}, None, False, steps=6, percepts=_percepts(down_up)))
            assert all(e.type != MemoryType.TASK_PROGRESS for e in memory.bank.entries)
            facts = {"recall": [chosen[0].text], "oracle": [cue], "none": []}[mode]
            pressed = f"the red button was pressed {presses}."
            assert memory.prompt(chosen) == build_prompt(INSTRUCTION, [*facts, pressed], task.prompt_template)
        memory.start(EnvFrame({}, {"blinks": 3}, None, False, steps=0, percepts=_percepts([0.13])),
                     np.random.default_rng(0))
        assert not memory.progress  # a new episode starts with no progress


def test_the_benchmarks_recall_states_the_presses_after_what_the_learner_retrieved(encoder):
    """MIKASA's harness agent builds its prompt from the recall schedule's facts: the retrieved one, then the presses
    written so far (a stateless controller that never saw them would press again and again)."""
    from types import SimpleNamespace

    from sb3_memret.benchmark.agent import RecalledFacts

    learner = SimpleNamespace(settings={"capacity": 6, "age_unit": "steps"},
                              keep_scores=lambda entries, ages, timescale: np.ones(len(entries)),
                              retrieve=lambda observation: np.array([0]))
    task = make_task(SPEC)
    schedule = RecalledFacts(task, learner, task.prompt_template, encoder, np.random.default_rng(0))
    start = EnvFrame({}, {"blinks": 3}, None, False, steps=0, percepts=_percepts([0.13]))
    schedule.start(start, task.episode(start))
    decoy = schedule.memory.bank.entries[0].text
    assert schedule.facts(0) == [decoy]
    schedule.observe(EnvFrame({}, {"blinks": 3}, None, False, steps=6,
                              percepts=_percepts([0.10, 0.05, 0.01, 0.05, 0.09, 0.13])))
    assert schedule.facts(1) == [decoy, "the red button was pressed once."]


@pytest.mark.slow
def test_written_or_counted_progress_lets_the_stateless_expert_press_as_often_as_the_cue_and_the_cue_alone_not():
    """Development seed 5001 of Medium (three blinks): with the facts the writer wrote (the count, then each press as
    it counts) the stateless expert presses three times and submits, and with the oracle (the count and MIKASA's
    press counter) too; with the cue's fact alone it never learns it pressed, presses a fourth time and fails."""
    from test_mikasa_seq_progress import CueFactsOnly

    from sb3_memret.evaluation.rollout import condition_schedule, play_task_episodes

    task = make_task(SPEC)
    for condition in ("written", "oracle"):
        facts: list[list[str]] = []
        schedule = condition_schedule(task, condition)
        original = schedule.facts
        schedule.facts = lambda decision: facts.append(list(original(decision))) or facts[-1]
        [played] = play_task_episodes(task.expert(), task, [DEV_SEED + 1], schedule, render_backend="cpu")
        assert played.success, (condition, facts[-1])
        assert facts[-1] == [CUE_FACT.format(count="three times"), "the red button was pressed three times."]
        pressed = [f[1] for f in facts if len(f) > 1]
        assert list(dict.fromkeys(pressed)) == [f"the red button was pressed {count_value(n)}." for n in (1, 2, 3)]
    [cue_only] = play_task_episodes(task.expert(), task, [DEV_SEED + 1], CueFactsOnly(task), render_backend="cpu")
    assert not cue_only.success


def test_a_recalled_demonstration_shows_a_decoy_until_the_writer_has_counted_the_blinks():
    """A recalled episode's prompts are what the recall condition's memory gives: a fact about another thing worded as
    the lamp's until the writer has read the blinks from the camera, then the lamp's true count. The expert acts and
    labels as if told nothing while the decoy shows, so a controller finetuned on it learns to ignore the decoy."""
    from sb3_memret.stage1.demos import DemoRecorder
    from sb3_memret.tasks.demos import DemoEpisode

    task = make_task("BlinkCountButtonPressEasy-VLA-v0")
    recorder = DemoRecorder(task, "cpu", frames="decisions", max_steps=44)
    act, heard = recorder.expert.act, []
    recorder.expert.act = lambda obs, prompts, *args: heard.extend(prompts) or act(obs, prompts, *args)
    try:
        recorded = recorder.record(DemoEpisode(DEV_SEED + 7, "recalled"))
    finally:
        recorder.env.close()
    true_fact = CUE_FACT.format(count=recorded.group)
    facts = [prompt.removeprefix(INSTRUCTION).strip() for prompt in recorded.prompts]
    first_true = next(i for i, f in enumerate(facts) if f.startswith(true_fact))
    assert 0 < first_true < len(facts) - 1  # the blinks take some decisions to be seen and counted
    decoy = facts[0]
    parsed = parse_prompt(recorded.prompts[0], task.prompt_template).facts
    assert len(parsed) == 1 and "lamp" not in decoy and decoy.endswith(("once.", "twice.", "three times."))
    assert facts[:first_true] == [decoy] * first_true  # the one decoy until the count is read, never the truth
    assert all(f.startswith(true_fact) and decoy not in f for f in facts[first_true:])
    # the expert acted and labelled on the prompt without the decoy: told nothing, then the same as shown
    assert heard == [INSTRUCTION] * first_true + recorded.prompts[first_true:]
