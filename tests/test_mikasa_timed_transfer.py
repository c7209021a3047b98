"""MIKASA TimedTransfer: the lamp read from pixels, the writer's count, facts that carry a time (``Task.facts_at``),
the controller's view, the timed carry expert, the task in the memory loop. Development seeds (5000+) only."""

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
from sb3_memret.tasks.mikasa.timed_transfer.task import (  # noqa: E402
    CUE_RELATION,
    INSTRUCTION,
    PROMPT_TEMPLATE,
    VARIANTS,
    SignalWriter,
    TimedTransferTask,
    count_value,
)

TASK = "TimedTransferEasy-VLA-v0"
FORBIDDEN = ("oracle", "signal", "lamp", "window", "goal")


@pytest.fixture(scope="module")
def task():
    return TimedTransferTask()


@pytest.fixture(scope="module")
def rgb_env(task):
    env = task.make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    yield env
    env.close()


def _frame(steps, percepts):
    return EnvFrame({}, {}, None, False, steps=steps, percepts=list(percepts))


def test_the_instruction_is_mikasas(rgb_env, task):
    stated = rgb_env.unwrapped._lang_instruction.lower().replace(". ", "; ")
    assert stated == INSTRUCTION.format(delay=100) == task.instruction(None)
    assert rgb_env.unwrapped.DELAY_STEPS == task.delay == 100


@pytest.mark.parametrize("env_id", sorted(VARIANTS))
def test_every_variant_is_registered_with_mikasas_delay_and_length(env_id):
    import gymnasium as gym
    from mani_skill.utils.registration import REGISTERED_ENVS
    from sb3_memret.benchmark.manifest import select_tasks

    task = make_task(env_id)
    delay, steps = VARIANTS[env_id]
    (row,) = select_tasks(env_ids=[env_id])
    assert task.max_control_steps == steps == row.max_episode_steps == gym.spec(env_id).max_episode_steps
    assert REGISTERED_ENVS[env_id].cls.DELAY_STEPS == delay == task.delay
    assert f"step {delay} of that count" in task.instruction(None)


def test_the_lamp_is_read_green_from_the_step_mikasa_lights_it(rgb_env, task):
    """The base camera shows the lamp green exactly from MIKASA's signal step on, never before."""
    for seed in (DEV_SEED, DEV_SEED + 1):
        obs, _ = rgb_env.reset(seed=seed)
        signal = int(rgb_env.unwrapped.signal_step[0])
        seen = [task.perceive(rgb_env, obs)]
        for _ in range(5):
            obs, *_ = rgb_env.step(np.zeros((1, 7), np.float32))
            seen.append(task.perceive(rgb_env, obs))
        assert seen == [step >= signal for step in range(6)]
        assert task.perception_window(rgb_env) == 4  # MIKASA lights it at step 1, 2 or 3


def test_the_writer_counts_from_the_first_green_frame_and_restarts_at_a_reset():
    writer = SignalWriter()
    assert writer.read(_frame(0, [False])) == []
    assert writer.read(_frame(4, [False, True, True, True])) == [(4, {("signal", "lamp"): "2 steps ago"})]
    assert writer.read(_frame(4, [])) == [(4, {("signal", "lamp"): "6 steps ago"})]  # past the window: it counts
    assert writer.read(_frame(0, [False])) == []  # a new episode
    assert writer.read(_frame(1, [False])) == []  # never green: nothing written


def test_facts_carry_the_time(rgb_env, task):
    obs, info = rgb_env.reset(seed=DEV_SEED)
    (frame,) = task.frames(rgb_env, obs, info, reset=True)
    episode = task.episode(frame)
    signal = int(rgb_env.unwrapped.signal_step[0])
    assert episode.group == f"step {signal}"
    assert task.facts_at("oracle", episode, signal - 1) == task.facts_at("wrong", episode, signal - 1) == []
    assert task.facts_at("oracle", episode, signal + 96) == ["the lamp turned green 96 steps ago."]
    assert task.facts_at("wrong", episode, signal + 10) == ["the lamp turned green 60 steps ago."]
    with pytest.raises(ValueError, match="facts_at"):
        task.oracle_facts(episode)
    with pytest.raises(ValueError, match="'none' has no facts"):
        task.facts_at("none", episode, 5)
    lamp = (MemoryType.OTHER, "lamp", CUE_RELATION)
    assert episode.is_true(MemoryEntry.create(*lamp, count_value(12), signal + 12))
    assert not episode.is_true(MemoryEntry.create(*lamp, count_value(12), signal + 13))
    assert not episode.is_true(MemoryEntry.create(MemoryType.OTHER, "key", CUE_RELATION, count_value(12), signal + 12))
    decoys = task.seed_memories(frame, episode, np.random.default_rng(0), SeedingConfig())
    assert len(decoys) == SeedingConfig().location_decoys
    for entry in decoys:
        assert entry.entity != "lamp" and not episode.is_true(entry)
        parse_prompt(f"{task.instruction(episode)} {entry.text}", PROMPT_TEMPLATE)
    with pytest.raises(ValueError, match=">= 0"):
        count_value(-1)


def test_prompts_parse_and_the_expert_waits_for_the_count(task):
    expert = task.expert()
    instruction = INSTRUCTION.format(delay=150)
    parsed = parse_prompt(build_prompt(instruction, ["the lamp turned green 140 steps ago."], PROMPT_TEMPLATE),
                          PROMPT_TEMPLATE)
    assert dict(parsed.instruction_fields) == {"delay": "150"} and parsed.field("count") == "140"
    assert not expert.due(parsed)
    assert expert.due(parse_prompt(f"{instruction} the lamp turned green 147 steps ago.", PROMPT_TEMPLATE))
    assert not expert.due(parse_prompt(instruction, PROMPT_TEMPLATE))  # no count: never
    with pytest.raises(ValueError, match="matches no trained template"):
        parse_prompt(f"{instruction} the lamp turned green soon.", PROMPT_TEMPLATE)


def test_wrapper_exposes_only_the_controllers_view(task):
    env = task.make_env(obs_mode="state_dict", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    try:
        assert leaked_keys(env.unwrapped.get_obs(), FORBIDDEN)  # the raw state holds the signal ...
        obs, _ = env.reset(seed=DEV_SEED)
        assert not leaked_keys(obs, FORBIDDEN)  # ... the controller's view does not
        assert set(obs["extra"]) == {"tcp_pose", "disc_positions", "disc_visible", "cube_position"}
        green, red = as_numpy(obs["extra"]["disc_positions"])[0]
        assert np.isclose(red[1] - green[1], 0.22, atol=1e-4)  # the red disc 22 cm to the robot's left
        assert np.allclose(as_numpy(obs["extra"]["cube_position"])[0, :2], green[:2], atol=1e-3)
    finally:
        env.close()
    names = task.demo_features(with_images=False)["observation.state"]["names"]
    assert "disc_red_x" in names and names[-3:] == ["cube_x", "cube_y", "cube_z"]


def test_an_unknown_variant_is_refused_naming_the_known_ones():
    with pytest.raises(ValueError, match="TimedTransferSlow-VLA-v0.*TimedTransferEasy-Long-VLA-v0"):
        TimedTransferTask("TimedTransferSlow-VLA-v0")


@pytest.mark.parametrize("condition, succeeds", [("written", True), ("none", False), ("wrong", False)])
def test_the_count_decides_the_episode(condition, succeeds):
    """Written: the writer's count from the camera carries the expert into MIKASA's window; without a count it never
    sets the cube down; with a count half the delay ahead it sets it down too early."""
    (result,) = evaluate_task_condition(make_task(TASK).expert(), condition, TASK, episodes=1, seed=DEV_SEED + 2,
                                        held_out=None)
    assert result.success is succeeds
    if condition == "written":  # in the window: the count 95-105 from the signal at step 1-3
        assert 96 <= result.steps <= 108


def test_the_lamp_fact_is_replaced_in_place_and_retrieved(encoder):
    """Recall with the true slot: the lamp's fact enters the bank once the lamp is green, keeps one slot as its count
    goes on (the writer's update replaces it), and the expert succeeds through it."""
    from sb3_memret.envs.vec_env import make_recall_vec_env

    venv = make_recall_vec_env(1, {"task": TASK, "controller": "scripted", "encoder": encoder, "replan_every": 4,
                                   "capacity": 6, "location_decoys": 5, "render_backend": "cpu"}, seed=0)
    try:
        venv.set_task_seeds([[DEV_SEED + 4]])
        venv.reset()
        memory = venv.venv.memories[0]
        done, counts = False, []
        while not done:
            lamp = [e for e in memory.bank.entries if e.entity == "lamp"]
            assert len(lamp) <= 1
            counts += [lamp[0].value] if lamp else []
            slot = memory.true_slot() if lamp else 0
            _, _, dones, infos = venv.step(np.array([[slot]]))
            done = bool(dones[0])
        assert infos[0]["success"] and len(set(counts)) == len(counts) > 20
    finally:
        venv.close()
