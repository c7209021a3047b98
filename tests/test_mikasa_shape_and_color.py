"""MIKASA RememberShapeAndColor3x2/3x3/5x3: the cue reader (shape and colour), the controller's view, the prompt
contract, the expert, the task."""

import numpy as np
import pytest
import torch

from mikasa_support import MIKASA_MISSING, leaked_keys

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.memory.schema import MemoryType  # noqa: E402
from sb3_memret.memory.seeding import SeedingConfig  # noqa: E402
from sb3_memret.controllers.prompts import parse_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.remember.shape_and_color import (  # noqa: E402
    CUE_KEY,
    INSTRUCTION,
    OBJECTS,
    PROMPT_TEMPLATE,
    RememberShapeAndColorTask,
    object_prompt,
    read_cue_object,
)

SIZES = {"RememberShapeAndColor3x2-VLA-v0": 6, "RememberShapeAndColor3x3-VLA-v0": 9,
         "RememberShapeAndColor5x3-VLA-v0": 15}
BIG = "RememberShapeAndColor5x3-VLA-v0"
FORBIDDEN = ("oracle", "task_cue", "goal_")


def _make(env_id: str, obs_mode: str):
    return RememberShapeAndColorTask(env_id).make_env(obs_mode=obs_mode, sim_backend="cpu", robot_uids="panda")


def _truth(info) -> str:
    shape, colour = (int(v) for v in info["oracle_info"][0])
    return OBJECTS[3 * shape + colour]


@pytest.fixture(scope="module")
def rgb_env():
    env = _make(BIG, "rgb")
    yield env
    env.close()


def test_the_three_sizes_are_registered_with_mikasas_objects_in_order():
    for env_id, n in SIZES.items():
        task = make_task(env_id)
        assert isinstance(task, RememberShapeAndColorTask) and task.words == OBJECTS[:n]
    assert OBJECTS[:6] == ("red cube", "lime cube", "blue cube", "red sphere", "lime sphere", "blue sphere")
    assert OBJECTS[6:9] == ("red t shape", "lime t shape", "blue t shape") and OBJECTS[-1] == "blue torus"
    with pytest.raises(ValueError, match="unknown RememberShapeAndColor task 'RememberShapeAndColor2x2-VLA-v0'"):
        RememberShapeAndColorTask("RememberShapeAndColor2x2-VLA-v0")


def test_reads_the_cue_object_and_nothing_else_on_rendered_frames(rgb_env):
    """At six development seeds of 5x3: every cue frame reads as the cue's colour and shape, no other frame reads."""
    read = set()
    for seed in range(5000, 5006):
        obs, info = rgb_env.reset(seed=seed)
        base, true = rgb_env.unwrapped, _truth(info)
        cue, hidden = int(base.cue_steps_per_env[0]), int(base.empty_steps_per_env[0])
        for step in range(cue + hidden + 2):
            word = read_cue_object(obs["sensor_data"]["base_camera"]["rgb"][0].numpy(), 15)
            assert word == (true if step < cue else None), (seed, step, word, true)
            obs, _, _, _, info = rgb_env.step(torch.zeros(1, 7))
        read.add(true)
    assert len(read) >= 4  # several shapes and colours among them
    with pytest.raises(ValueError, match="n_objects must be in 1..15"):
        read_cue_object(np.zeros((128, 128, 3), np.uint8), 16)


def test_an_object_out_of_play_reads_as_none(rgb_env):
    obs, info = rgb_env.reset(seed=5000)
    frame = obs["sensor_data"]["base_camera"]["rgb"][0].numpy()
    true = _truth(info)
    index = OBJECTS.index(true)
    assert read_cue_object(frame, 15) == true
    assert read_cue_object(frame, index) is None  # its shape or colour is not among the first `index` objects


def test_wrapper_exposes_only_the_controllers_view_with_every_object():
    env = _make("RememberShapeAndColor3x3-VLA-v0", "state_dict")
    try:
        obs, _ = env.reset(seed=5000)
        assert set(obs["extra"]) == {"tcp_pose", "object_positions", "object_visible"}
        assert not leaked_keys(obs, FORBIDDEN)
        assert tuple(obs["extra"]["object_positions"].shape) == (1, 9, 3)
        assert int(obs["extra"]["object_visible"].sum()) == 1  # the cue phase: the cue object alone
    finally:
        env.close()


def test_prompts_parse_with_the_object_fact():
    assert parse_prompt(INSTRUCTION, PROMPT_TEMPLATE).facts == ()
    for word in OBJECTS:
        prompt = object_prompt(word)
        assert prompt == f"{INSTRUCTION} the cue object was a {word}."
        (fact,) = parse_prompt(prompt, PROMPT_TEMPLATE).facts
        assert dict(fact.fields) == {"entity": "cue object", "object": word}
    (decoy,) = parse_prompt(f"{INSTRUCTION} the key was a lime t shape.", PROMPT_TEMPLATE).facts  # worded alike
    assert dict(decoy.fields) == {"entity": "key", "object": "lime t shape"}
    with pytest.raises(ValueError, match="matches no trained template"):
        parse_prompt(f"{INSTRUCTION} the cue cube was red.", PROMPT_TEMPLATE)  # RememberColor's fact


@pytest.mark.parametrize("env_id", ["RememberShapeAndColor3x2-VLA-v0", BIG])
def test_the_expert_touches_the_object_of_both_shape_and_colour(env_id):
    """Oracle succeeds; the wrong fact (the same shape in the next colour, or the next shape) fails; at the end every
    object is in the detector's view."""
    task = make_task(env_id)
    env = _make(env_id, "state_dict")
    expert = task.expert()
    try:
        expert.check_env(env)
        for seed, condition in ((5000, "oracle"), (5001, "oracle"), (5002, "wrong")):
            obs, info = env.reset(seed=seed)
            true = _truth(info)
            word = true if condition == "oracle" else task.words[(task.words.index(true) + 1) % len(task.words)]
            expert.reset([seed])
            success = False
            for step in range(25):
                if step % 4 == 0:
                    chunk = expert.act(obs, [object_prompt(word)])[0]
                obs, _, _, _, info = env.step(torch.from_numpy(chunk[step % 4][None]).float())
                success |= bool(info["success"][0])
            visible = obs["extra"]["object_visible"]
            assert bool(visible.all()) and visible.shape[1] == SIZES[env_id]
            assert success == (condition == "oracle"), (seed, condition, true)
    finally:
        env.close()


def test_task_contract(rgb_env):
    task = RememberShapeAndColorTask(BIG)
    assert task.perceives_every_step and task.default_render_backend == "cpu" and task.max_control_steps == 25
    obs, info = rgb_env.reset(seed=5000)
    (frame,) = task.frames(rgb_env, obs, info, reset=True)
    episode = task.episode(frame)
    true = _truth(info)
    assert episode.group == true and episode.true_facts == ((CUE_KEY, true),)
    assert task.perceive(rgb_env, obs) == true
    assert task.oracle_facts(episode) == [f"the cue object was a {true}."]
    wrong = OBJECTS[(OBJECTS.index(true) + 1) % 15]
    assert task.wrong_facts(episode) == [f"the cue object was a {wrong}."]
    frame.percepts, frame.steps = [None, true], 2
    assert task.writer().read(frame) == [(2, {("cue", "cue object"): true})]
    assert task.writer().relations == {"cue": (MemoryType.OTHER, "was_a")}
    for entry in task.seed_memories(frame, episode, np.random.default_rng(0), SeedingConfig()):
        assert entry.value in OBJECTS and entry.text == f"the {entry.entity} was a {entry.value}."
        parse_prompt(f"{INSTRUCTION} {entry.text}", PROMPT_TEMPLATE)
    names = task.demo_features(with_images=False)["observation.state"]["names"]
    assert "object_red_cube_x" in names and "object_blue_torus_visible" in names
