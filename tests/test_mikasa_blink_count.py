"""MIKASA BlinkCountButtonPress (Easy, Medium): the lamp's bulb mesh put in place, the blinks counted from pixels, the
prompt contract with counts in words, the controller's view, the press expert that counts its own presses, the task
in the rollout loop and in MIKASA's harness."""

import numpy as np
import pytest
import torch

from mikasa_support import MIKASA_MISSING, leaked_keys

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.memory.schema import MemoryEntry, MemoryType  # noqa: E402
from sb3_memret.memory.seeding import SeedingConfig  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt, parse_prompt  # noqa: E402
from sb3_memret.evaluation.rollout import evaluate_task_condition  # noqa: E402
from sb3_memret.tasks import make_task, task_names  # noqa: E402
from sb3_memret.tasks.base import EnvFrame  # noqa: E402
from sb3_memret.tasks.mikasa.blink_count.task import (  # noqa: E402
    CUE_FACT,
    INSTRUCTION,
    LONGEST_GAP,
    PROMPT_TEMPLATE,
    VARIANTS,
    BlinkCountTask,
    BlinkWriter,
)
from sb3_memret.tasks.mikasa.core.cue_task import DEV_SEED  # noqa: E402
from sb3_memret.tasks.mikasa.core.lamp_asset import LAMP_SHA256, SHIPPED_LAMP, install_lamp_asset  # noqa: E402
from sb3_memret.tasks.mikasa.blink_count.expert import count_value, parse_count, stated_count  # noqa: E402

EASY, MEDIUM = "BlinkCountButtonPressEasy-VLA-v0", "BlinkCountButtonPressMedium-VLA-v0"
FORBIDDEN = ("oracle", "task_cue", "target_blinks", "press_count", "pending", "indicator", "submit", "lift", "ready")


@pytest.fixture(scope="module")
def medium():
    """The task without progress facts: its expert counts its own presses (progress as memory has its own tests)."""
    return BlinkCountTask(MEDIUM, progress=False)


@pytest.fixture(scope="module")
def state_env(medium):
    """State mode (no cameras: fast): the raw observation holds MIKASA's counters, which the view drops."""
    env = medium.make_env(obs_mode="state_dict", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    yield env
    env.close()


@pytest.fixture(scope="module")
def rgb_env(medium):
    env = medium.make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    yield env
    env.close()


def _prompt(task, count):
    facts = [] if count is None else [CUE_FACT.format(count=count_value(count))]
    return build_prompt(task.instruction_text, facts, task.prompt_template)


def test_six_ids_as_mikasa_registers_them():
    import gymnasium as gym
    from mikasa_robo_suite.vla.memory_envs import blink_count_button_press_vla as mikasa
    from mikasa_robo_suite.vla.utils.apply_wrappers import VLA_WRAPPER_CONFIGS

    classes = {name: getattr(mikasa, name.replace("-", "").replace("v0", "Env"))
               for name in VARIANTS}
    assert len(VARIANTS) == 6 and set(VARIANTS) <= set(task_names())
    for name, variant in VARIANTS.items():
        task = make_task(name)
        assert task.name == name and task.perceives_every_step and task.replan_every == 4
        assert task.max_control_steps == variant.steps == gym.spec(name).max_episode_steps
        assert list(classes[name].BLINK_COUNT_RANGE) == [variant.min_blinks, variant.max_blinks]
        assert classes[name].BLINK_OFF_STEPS[1] == LONGEST_GAP
        assert VLA_WRAPPER_CONFIGS[name].curriculum_wrapper is None and not task.noop_before_manipulation
    assert INSTRUCTION == mikasa.BlinkCountButtonPressVLABaseEnv.LANGUAGE_INSTRUCTION.lower()
    with pytest.raises(ValueError, match=EASY):
        BlinkCountTask("BlinkCountButtonPressHarder-VLA-v0")


def test_long_counts_are_words_and_wrong_counts_stay_in_the_variants_range():
    assert [count_value(n) for n in (10, 13, 20, 21, 29, 30)] == [
        "ten times", "thirteen times", "twenty times", "twenty one times", "twenty nine times", "thirty times"]
    task = make_task("BlinkCountButtonPressMedium-Long-VLA-v0")
    parsed = parse_prompt(f"{INSTRUCTION} the blue lamp blinked twenty one times.", PROMPT_TEMPLATE)
    assert stated_count(parsed) == 21
    for n, wrong in ((10, 11), (19, 20), (20, 10)):
        episode = task.episode(EnvFrame({}, {"blinks": n}, None, False))
        assert task.wrong_facts(episode) == [CUE_FACT.format(count=count_value(wrong))]
    easy = make_task(EASY)
    assert easy.wrong_facts(easy.episode(EnvFrame({}, {"blinks": 3}, None, False))) == [CUE_FACT.format(count="once")]
    with pytest.raises(ValueError, match="a count must be 1-30, got 31"):
        count_value(31)


def test_the_lamp_mesh_is_mikasas_file_and_in_place():
    import hashlib

    assert hashlib.sha256(SHIPPED_LAMP.read_bytes()).hexdigest() == LAMP_SHA256
    placed = install_lamp_asset()
    assert placed.name == SHIPPED_LAMP.name and placed.read_bytes() == SHIPPED_LAMP.read_bytes()


def test_the_prompt_contract_states_counts_in_words(medium):
    assert [count_value(n) for n in (1, 2, 3, 5)] == ["once", "twice", "three times", "five times"]
    prompt = _prompt(medium, 3)
    assert prompt == f"{INSTRUCTION} the blue lamp blinked three times."
    parsed = parse_prompt(prompt, PROMPT_TEMPLATE)
    assert dict(parsed.facts[0].fields) == {"entity": "blue lamp", "count": "three times"} and stated_count(parsed) == 3
    decoy_first = parse_prompt(f"{INSTRUCTION} the key blinked once. the blue lamp blinked twice.", PROMPT_TEMPLATE)
    assert stated_count(decoy_first) == 1  # the first count it reads, whatever the fact is about
    assert stated_count(parse_prompt(INSTRUCTION, PROMPT_TEMPLATE)) is None
    assert parse_count("three times") == 3 and parse_count("thrice") is None
    with pytest.raises(ValueError, match="matches no trained template"):  # digits: not a field of the contract
        parse_prompt(f"{INSTRUCTION} the blue lamp blinked 3 times.", PROMPT_TEMPLATE)
    # the writer's memory reads as the oracle's fact
    entry = MemoryEntry.create(MemoryType.OTHER, "blue lamp", "blinked", "three times", 0)
    assert entry.text == "the blue lamp blinked three times."


def test_the_writer_counts_dark_to_lit_changes_until_the_cue_ends():
    def frame(percepts, reset=False):
        return EnvFrame({}, None, None, False, steps=0 if reset else len(percepts), percepts=percepts)

    dark, lit, green = (False, False), (True, False), (False, True)
    writer = BlinkWriter()
    assert writer.read(frame([dark], reset=True)) == []
    # two blinks of 3 lit steps, dark gaps of 4, then the phase lamp green at the chunk's 16th step
    assert writer.read(frame([dark, lit, lit, lit, dark, dark, dark, dark])) == []
    written = writer.read(frame([lit, lit, lit, dark, dark, dark, dark, green]))
    assert written == [(8, {("blinks", "blue lamp"): "twice"})]
    assert writer.read(frame([lit, lit, dark, green])) == []  # once per episode
    # a new episode, the phase lamp never seen green: written once the lamp has been dark longer than any gap
    assert writer.read(frame([dark], reset=True)) == []
    chunk = [lit, lit, lit] + [dark] * (LONGEST_GAP + 1)
    assert writer.read(frame(chunk)) == [(LONGEST_GAP + 4, {("blinks", "blue lamp"): "once"})]
    assert writer.read(frame([dark], reset=True)) == [] and writer.read(frame([dark] * 8 + [green])) == []  # unseen


@pytest.mark.parametrize("seed", [DEV_SEED, DEV_SEED + 8])  # Medium's 2 and 5 blinks
def test_the_camera_counts_the_blinks(medium, rgb_env, seed):
    """The blinks read from the base camera's frames at every step (the arm at rest), written as the phase lamp
    turns green, equal MIKASA's count."""
    obs, info = rgb_env.reset(seed=seed)
    (frame,) = medium.frames(rgb_env, obs, info, reset=True)
    frame.percepts = [medium.perceive(rgb_env, obs)]
    writer, written = medium.writer(), []
    assert writer.read(frame) == [] and frame.percepts == [(False, False)]
    cue_end = int(rgb_env.unwrapped.cue_steps_per_env[0])
    for step in range(1, cue_end + 1):
        obs, *_ = rgb_env.step(torch.zeros(1, 7))
        later = EnvFrame({}, None, None, False, steps=1, percepts=[medium.perceive(rgb_env, obs)])
        written += [(step, predicates) for _, predicates in writer.read(later)]
    truth = medium.episode(frame).true_facts[0][1]
    assert written == [(cue_end, {("blinks", "blue lamp"): truth})]
    assert truth == count_value(int(rgb_env.unwrapped.target_blinks[0]))


def test_the_view_shows_the_buttons_and_the_phase_lamp_only(medium, state_env):
    obs, info = state_env.reset(seed=DEV_SEED + 9)
    assert set(obs) == {"agent", "extra", "sensor_data"} and not leaked_keys(obs, FORBIDDEN)
    assert set(obs["extra"]) == {"tcp_pose", "button_positions", "button_visible", "lamp_green"}
    base = state_env.unwrapped
    assert torch.allclose(obs["extra"]["button_positions"][0, 0], base.button_base.pose.p[0])
    assert torch.allclose(obs["extra"]["button_positions"][0, 1], base.confirm_button_base.pose.p[0])
    assert not bool(obs["extra"]["lamp_green"][0])
    for _ in range(int(base.cue_steps_per_env[0])):
        obs, *_ = state_env.step(torch.zeros(1, 7))
    assert bool(obs["extra"]["lamp_green"][0])
    names = medium.demo_features(with_images=False)["observation.state"]["names"]
    assert "button_black_visible" in names and names[-1] == "lamp_green"
    assert medium.demo_frame(obs, with_images=False)["observation.state"].shape == (len(names),)


def test_task_contract(medium, state_env):
    obs, info = state_env.reset(seed=DEV_SEED + 1)
    (frame,) = medium.frames(state_env, obs, info, reset=True)
    episode = medium.episode(frame)
    assert episode.true_facts == (((MemoryType.OTHER, "blue lamp", "blinked"), "three times"),)
    assert medium.oracle_facts(episode) == ["the blue lamp blinked three times."]
    assert medium.wrong_facts(episode) == ["the blue lamp blinked four times."]
    five = medium.episode(EnvFrame({}, {"blinks": 5}, None, False))
    assert medium.wrong_facts(five) == ["the blue lamp blinked once."]
    for entry in medium.seed_memories(frame, episode, np.random.default_rng(0), SeedingConfig()):
        assert entry.entity != "blue lamp" and parse_count(entry.value) in range(1, 6)
        parse_prompt(f"{INSTRUCTION} {entry.text}", PROMPT_TEMPLATE)
    assert not frame.success and medium.development_seeds(2) == [DEV_SEED, DEV_SEED + 1]


def _run(env, task, seed, count):
    """One episode with the expert and a fixed prompt; MIKASA's success, and its counted presses."""
    obs, _ = env.reset(seed=seed)
    expert, prompt = task.expert(), _prompt(task, count)
    expert.check_env(env)
    expert.reset([seed])
    success, info = False, {}
    for step in range(task.max_control_steps):
        if step % task.replan_every == 0:
            chunk = expert.act(obs, [prompt])[0]
        obs, _, terminated, truncated, info = env.step(torch.from_numpy(chunk[step % task.replan_every][None]).float())
        success |= bool(info["success"][0])
        if terminated or truncated:
            break
    return success, int(info["press_count"][0]), expert.progress[0].presses


def test_the_expert_presses_as_often_as_its_prompt_says(medium, state_env):
    """Three blinks: with the true count the expert presses three times (as it counted them, so did MIKASA) and
    submits; one press too many ends the episode at that press, one too few (the guess without a fact) at the
    submission."""
    seed = DEV_SEED + 1
    assert _run(state_env, medium, seed, 3) == (True, 3, 3)
    assert _run(state_env, medium, seed, 4)[0] is False
    assert _run(state_env, medium, seed, None) == (False, 1, 1)


def test_the_expert_is_batched_and_counts_per_env(medium):
    expert = medium.expert()
    expert.reset([1, 2])
    qpos = np.tile([0, 0, 0, -2.09, 0, 2.09, 0.79, 0.0, 0.0], (2, 1))
    red, black = [-0.1, 0.0, 0.015], [-0.1, 0.16, 0.015]
    low = [-0.1, 0.0, 0.015 + 0.043 + 0.01, 0, 1, 0, 0]  # the TCP 1 cm over the red cap's top
    obs = {"agent": {"qpos": qpos, "qvel": np.zeros((2, 9))},
           "extra": {"tcp_pose": np.array([low, low]), "button_positions": np.array([[red, black]] * 2),
                     "button_visible": np.ones((2, 2), bool), "lamp_green": np.array([True, False])}}
    chunks = expert.act(obs, [_prompt(medium, 2)] * 2)
    assert chunks.shape == (2, 8, 7) and np.all(chunks[:, :, 6] == -1.0)  # fingers closed
    assert expert.progress[0].lifting and not expert.progress[1].lifting  # the cue: no press counts yet
    assert chunks[0, 0, 2] > 0.5  # pressed: lifts
    expert.reset_envs([0], [3])
    assert not expert.progress[0].lifting


def test_the_task_runs_through_the_rollout(medium):
    """Two Easy episodes at development seeds (2 blinks, then 1), the writer's fact from the camera in the prompt."""
    task = make_task(EASY)
    results = evaluate_task_condition(task.expert(), "written", task, episodes=2, seed=DEV_SEED + 8,
                                      held_out=None)
    assert [(r.group, r.success) for r in results] == [("twice", True), ("once", True)]


def test_the_count_is_written_and_retrieved(encoder):
    """Recall with the true slot: the writer's fact reaches the bank from the camera as the cue ends, is the true one,
    and the expert presses through it (one blink: its guess without a fact would succeed too, so the fact must be
    the one retrieved at every decision after it)."""
    from sb3_memret.envs.vec_env import make_recall_vec_env

    venv = make_recall_vec_env(1, {"task": EASY, "controller": "scripted", "encoder": encoder, "replan_every": 4,
                                   "capacity": 6, "location_decoys": 5, "render_backend": "cpu"}, seed=0)
    try:
        venv.set_task_seeds([[DEV_SEED + 9]])
        venv.reset()
        memory = venv.venv.memories[0]
        done, success, hits, texts = False, False, 0, []
        while not done:  # until the fact is written, the empty last slot: no decoy reaches the prompt
            slot = memory.true_slot()
            texts = [e.text for e in memory.bank.entries if e.entity == "blue lamp"]  # before the auto-reset
            _, _, dones, infos = venv.step(np.array([[slot if slot >= 0 else 5]]))
            done, success = bool(dones[0]), success or bool(infos[0]["success"])
            hits += slot >= 0 and bool(infos[0]["retrieved_true"])
        assert texts == ["the blue lamp blinked once."] and hits >= 3 and success, (texts, hits)
    finally:
        venv.close()


@pytest.mark.slow
def test_the_agent_plays_blink_count_in_mikasas_harness(tmp_path, monkeypatch):
    """Real episodes in MIKASA's own harness at a development seed: the written count and presses are the oracle's
    and both succeed, the wrong count fails, nothing forbidden is read."""
    import json

    from test_benchmark import _Guarded

    from sb3_memret.benchmark import agent as agent_module
    from sb3_memret.benchmark.runner import Protocol, plan, run_benchmark

    forward = agent_module.MemoryAgent.forward
    monkeypatch.setattr(agent_module.MemoryAgent, "forward", lambda self, obs: forward(self, _Guarded(obs)))
    run = plan(Protocol(seed_set="dev", episodes=1), ["oracle", "wrong", "written"], env_ids=[EASY])
    content = run_benchmark(run, tmp_path, workers=1)
    cells = content["tasks"][EASY]["conditions"]
    assert {c: cells[c]["successes"] for c in cells} == {"oracle": [True], "wrong": [False], "written": [True]}
    prompts = {r["condition"]: r["prompt"] for r in map(json.loads, (tmp_path / "episodes.jsonl").open())}
    # the last prompt: the count, then the presses (written from the cameras, or MIKASA's counter for the oracle)
    expected = f"{INSTRUCTION} the blue lamp blinked three times. the red button was pressed three times."
    assert prompts["written"] == prompts["oracle"] == expected
