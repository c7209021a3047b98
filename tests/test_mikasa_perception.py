"""MIKASA RememberColor: the pixel cue reader, the controller's view of the env, and the scripted expert."""

import numpy as np
import pytest
import torch

from mikasa_support import MIKASA_MISSING, leaked_keys

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controllers.prompts import parse_prompt  # noqa: E402
from sb3_memret.tasks.mikasa.core.touch_expert import (  # noqa: E402
    INSTRUCTION,
    PROMPT_TEMPLATE,
    ScriptedTouchController,
    colour_prompt,
)
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES, read_cue_colour  # noqa: E402

SEEDS = (5000, 5001, 5002)  # development seeds: MIKASA's evaluation seeds (4242424242 + i) stay unseen
FORBIDDEN = ("oracle", "task_cue", "goal_")


def _make(env_id: str, obs_mode: str):
    from sb3_memret.common.rendering import use_cpu_renderer

    use_cpu_renderer()
    import gymnasium as gym
    from mikasa_robo_suite.vla.utils.wrappers import CurriculumPhaseNoopActionWrapper

    from sb3_memret.tasks.mikasa.core.perception import ControllerObservation

    env = gym.make(env_id, num_envs=1, obs_mode=obs_mode, control_mode="pd_ee_delta_pose", render_backend="cpu",
                   sim_backend="cpu", reward_mode="normalized_dense")
    return ControllerObservation(CurriculumPhaseNoopActionWrapper(env))


@pytest.fixture(scope="module")
def rgb_env():
    env = _make("RememberColor9-VLA-v0", "rgb")
    yield env
    env.close()


@pytest.fixture(scope="module")
def state_env():
    """State mode: the raw observation holds oracle_info and goal_{i}_pose, which the wrapper must drop."""
    env = _make("RememberColor9-VLA-v0", "state_dict")
    yield env
    env.close()


def _phase(base, elapsed: int) -> str:
    cue = int(base.cue_steps_per_env[0])
    return "cue" if elapsed < cue else "delay" if elapsed < cue + int(base.empty_steps_per_env[0]) else "manip"


@pytest.mark.parametrize("seed", SEEDS)
def test_reads_the_cue_and_nothing_else_on_rendered_frames(rgb_env, seed):
    obs, info = rgb_env.reset(seed=seed)
    base = rgb_env.unwrapped
    true = COLOUR_NAMES[int(info["oracle_info"][0])]
    seen = []
    for _ in range(30):
        elapsed = int(info["elapsed_steps"][0])
        phase = _phase(base, elapsed)
        reading = read_cue_colour(obs["sensor_data"]["base_camera"]["rgb"][0].numpy(), 9)
        seen.append((phase, reading))
        if phase == "manip" and elapsed >= base.cue_steps_per_env[0] + base.empty_steps_per_env[0] + 1:
            break
        obs, _, _, _, info = rgb_env.step(torch.zeros(1, 7))
    assert [r for p, r in seen if p == "cue"] == [true] * int(base.cue_steps_per_env[0])
    assert all(r is None for p, r in seen if p != "cue"), seen


def test_a_second_cube_or_none_reads_as_none(rgb_env):
    obs, _ = rgb_env.reset(seed=SEEDS[0])
    frame = obs["sensor_data"]["base_camera"]["rgb"][0].numpy()
    assert read_cue_colour(frame, 9) is not None
    blank = frame.copy()
    blank[70:85, 55:72] = frame[40:55, 55:72]  # table wood over the cue
    assert read_cue_colour(blank, 9) is None
    twice = frame.copy()
    twice[74:80, 20:24] = frame[74:80, 62:66]  # the cue cube pasted a second time
    assert read_cue_colour(twice, 9) is None


def test_wrapper_exposes_only_the_controllers_view(state_env):
    obs, _ = state_env.reset(seed=SEEDS[0])
    assert set(obs) == {"agent", "extra", "sensor_data"}
    assert set(obs["agent"]) == {"qpos", "qvel"}
    assert set(obs["extra"]) == {"tcp_pose", "cube_positions", "cube_visible"}
    assert not leaked_keys(obs, FORBIDDEN)
    assert tuple(obs["extra"]["cube_positions"].shape) == (1, 9, 3)
    visible = obs["extra"]["cube_visible"][0].numpy()
    assert visible.sum() == 1  # the cue phase: the target alone, at the table centre
    hidden = obs["extra"]["cube_positions"][0].numpy()[~visible]
    assert np.all(hidden == 0)  # parked cubes (z = 1000) are neither visible nor located


def test_wrapper_drops_oracle_keys_of_rgb_mode_too(rgb_env):
    obs, _ = rgb_env.reset(seed=SEEDS[1])
    assert not leaked_keys(obs, FORBIDDEN)
    assert set(obs["sensor_data"]["base_camera"]) == {"rgb"}


def test_prompts_parse_with_the_colour_fact():
    assert parse_prompt(INSTRUCTION, PROMPT_TEMPLATE).facts == ()
    for colour in COLOUR_NAMES:
        (fact,) = parse_prompt(colour_prompt(colour), PROMPT_TEMPLATE).facts
        assert dict(fact.fields) == {"entity": "cue cube", "colour": colour}
    (decoy,) = parse_prompt(f"{INSTRUCTION} the key was blue.", PROMPT_TEMPLATE).facts  # worded alike: it misleads
    assert dict(decoy.fields) == {"entity": "key", "colour": "blue"}


def test_expert_holds_still_without_a_fact_and_moves_with_one(state_env):
    expert = ScriptedTouchController()
    expert.check_env(state_env)
    obs, info = state_env.reset(seed=SEEDS[0])
    for _ in range(12):  # into the manipulation phase: every cube in sight
        obs, *_ = state_env.step(torch.zeros(1, 7))
    assert bool(obs["extra"]["cube_visible"].all())
    expert.reset([0])
    assert np.all(expert.act(obs, [colour_prompt(None)]) == 0)
    assert np.all(expert.act(obs, [colour_prompt("purple")]) == 0)  # parses, but names no cube
    chunk = expert.act(obs, [colour_prompt("teal")])
    assert chunk.shape == (1, 8, 7) and np.abs(chunk[0, 0, :3]).max() > 0.5


def _two_envs_obs() -> dict:
    """Two envs at the reset pose: red at +y, lime at -y, blue out of sight."""
    return {
        "agent": {"qpos": np.tile([0, 0, 0, -2.09, 0, 2.09, 0.79, 0.04, 0.04], (2, 1)), "qvel": np.zeros((2, 9))},
        "extra": {"tcp_pose": np.tile([-0.07, 0, 0.32, 0, 1, 0, 0], (2, 1)),
                  "cube_positions": np.tile([[-0.1, 0.1, 0.02], [0.0, -0.1, 0.02], [0, 0, 0]], (2, 1, 1)),
                  "cube_visible": np.tile([True, True, False], (2, 1))},
    }


def test_expert_is_batched():
    expert = ScriptedTouchController()
    expert.reset([1, 2])
    obs = _two_envs_obs()
    chunks = expert.act(obs, [colour_prompt("red"), colour_prompt(None)])
    assert chunks.shape == (2, 8, 7)
    assert chunks[0, 0, 1] > 0 and np.all(chunks[1] == 0)  # env 0 heads for red (+y), env 1 holds still
    with pytest.raises(ValueError):
        expert.reset_envs([2], [0])


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ["RememberColor3-VLA-v0", "RememberColor5-VLA-v0", "RememberColor9-VLA-v0"])
def test_expert_touches_the_named_cube(env_id):
    env = _make(env_id, "state_dict")
    expert = ScriptedTouchController()
    wins = {"oracle": 0, "none": 0}
    for i in range(10):
        for condition in wins:
            obs, info = env.reset(seed=SEEDS[0] + i)
            prompt = colour_prompt(COLOUR_NAMES[int(info["oracle_info"][0])] if condition == "oracle" else None)
            expert.reset([0])
            success = False
            for step in range(25):
                if step % 4 == 0:
                    chunk = expert.act(obs, [prompt])[0]
                obs, _, _, truncated, info = env.step(torch.from_numpy(chunk[step % 4][None]).float())
                success |= bool(info["success"][0])
            wins[condition] += success
    env.close()
    assert wins["oracle"] >= 9 and wins["none"] == 0, wins


def test_an_expert_with_a_default_guesses_it_without_a_fact():
    """The task's expert touches its default colour (red) when the prompt names none it knows, as a finetuned
    policy would guess; a default outside the vocabulary is refused."""
    expert = ScriptedTouchController(vocabulary=COLOUR_NAMES[:3], default="red")
    expert.reset([1, 2])
    obs = _two_envs_obs()
    guessed, named = expert.act(obs, [colour_prompt(None), colour_prompt("lime")])
    assert guessed[0, 1] > 0 and named[0, 1] < 0  # red at +y, lime at -y
    with pytest.raises(ValueError, match="default colour 'teal' is not one of"):
        ScriptedTouchController(vocabulary=COLOUR_NAMES[:3], default="teal")
