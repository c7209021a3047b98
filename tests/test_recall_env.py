"""The decision-level env on the real simulator with the scripted controller."""

from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env

from sb3_memret.envs import RECALL_ENV_ID
from sb3_memret.envs.configs import MemoryConfig
from sb3_memret.envs.recall_memory import EpisodeMemory
from sb3_memret.memory.schema import MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.physics.backends import TaskRunner
from sb3_memret.tasks.drawer.prompts import TEMPLATE
from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer.cabinet import LAYERS
from sb3_memret.tasks.drawer.household import HouseholdConfig
from sb3_memret.tasks.drawer.objects import OBJECT_SETS
from sb3_memret.tasks.drawer.seeding import location_memory
from sb3_memret.policy.networks import RetentionScorer


@pytest.fixture(scope="module")
def recall_env(encoder):
    env = gym.make(RECALL_ENV_ID, encoder=encoder, max_control_steps=80)
    yield env
    env.close()


def _long_term(long_term_capacity: int, age_unit: str = "steps") -> MemoryConfig:
    """Three per-episode slots after a long-term store, written from what the robot saw, no decoys."""
    return MemoryConfig(3, long_term_capacity, "observed", age_unit=age_unit, seeding=SeedingConfig(location_decoys=0))


def _household(**lives) -> DrawerTask:
    return DrawerTask(household=HouseholdConfig(**lives))


def test_sb3_check_env_passes(recall_env):
    with pytest.warns(UserWarning, match="unconventional shape"):  # bank arrays need the custom policy
        check_env(recall_env.unwrapped, warn=True, skip_render_check=True)


def test_seeded_bank_and_observation(recall_env):
    obs, info = recall_env.reset(seed=3, options={"target_layer": 2})
    assert obs["memories"].shape == (6, 384) and obs["mask"].sum() == 6
    np.testing.assert_allclose(np.linalg.norm(obs["memories"], axis=1), 1.0, atol=1e-5)
    texts = info["memory_texts"]
    assert len(texts) == 6 and info["target_layer"] == 2
    if info["true_slot"] >= 0:
        assert texts[info["true_slot"]] == "the cube is in drawer layer 2."
    else:
        assert info["true_evicted"]


def test_retrieving_the_true_memory_earns_more_than_a_decoy(recall_env):
    returns = {}
    for pick in ("true", "decoy"):
        obs, info = recall_env.reset(seed=4, options={"target_layer": 3})
        assert info["true_slot"] >= 0
        texts = info["memory_texts"]
        decoy = next(i for i, t in enumerate(texts) if "drawer layer" in t and i != info["true_slot"])
        total = 0.0
        for _ in range(10):  # 80 control steps: reaching the right handle, or the wrong one
            slot = info["true_slot"] if pick == "true" else decoy
            obs, reward, terminated, truncated, info = recall_env.step(np.array([slot]))
            total += reward
            assert info["retrieved_true"] == (pick == "true")
        returns[pick] = total
    assert returns["true"] > returns["decoy"]


def test_retention_weights_drive_eviction(encoder):
    env = gym.make(RECALL_ENV_ID, encoder=encoder).unwrapped
    scorer = RetentionScorer()
    env.set_retention_weights(scorer.state_dict(), "steps")
    for seed in range(5):
        env.reset(seed=seed)
        assert len(env.bank) == 6  # 7 distinct keys competed for 6 slots
    env.close()


def test_bad_arguments_are_refused(recall_env):
    recall_env.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions must be 1 slot indices in \[0, 6\)"):
        recall_env.step(np.array([6]))
    with pytest.raises(ValueError, match="unknown mode 'guess'"):
        gym.make(RECALL_ENV_ID, mode="guess")


def test_several_objects_the_instruction_names_the_target(encoder):
    env = gym.make(RECALL_ENV_ID, encoder=encoder, max_control_steps=80, objects="train", n_objects=3,
                   location_decoys=2, holding_decoys=2).unwrapped
    targets = set()
    for seed in range(6):
        obs, info = env.reset(seed=seed)
        target, layer = info["target"], info["target_layer"]
        targets.add(target)
        assert env.instruction() == f"pick out the {target}."
        texts = info["memory_texts"]
        located = [t for t in texts if t.endswith(".") and " is in drawer layer " in t]
        assert len(texts) == 6 and len(located) == 5  # the three placed objects and two absent ones
        assert texts[info["true_slot"]] == f"the {target} is in drawer layer {layer}."
        np.testing.assert_allclose(obs["instruction"], encoder.encode_one(f"pick out the {target}."), atol=1e-6)
        other = next(i for i, t in enumerate(texts) if t in located and i != info["true_slot"])
        obs, _, _, _, info = env.step(np.array([other]))
        assert info["prompt"] == f"pick out the {target}. {texts[other]}" and not info["retrieved_true"]
    assert len(targets) > 1
    env.close()


def test_held_out_objects_are_never_in_a_training_bank(encoder):
    env = gym.make(RECALL_ENV_ID, encoder=encoder, objects="heldout", n_objects=3, mode="oracle").unwrapped
    _, info = env.reset(seed=0)
    assert info["target"] in OBJECT_SETS["heldout"]
    assert env.instruction() == f"pick out the {info['target']}. the {info['target']} is in drawer layer " \
                                f"{info['target_layer']}."
    env.close()
    assert not set(OBJECT_SETS["heldout"]) & (set(OBJECT_SETS["train"]) | set(SeedingConfig().vocabulary))


def test_observed_memory_comes_from_what_the_robot_saw_alone(encoder):
    kwargs = dict(objects=OBJECT_SETS["train"], n_objects=3)
    runner = TaskRunner({"obs_mode": "state_dict", "render_backend": "none", **kwargs}, 80, "drawer")
    config = MemoryConfig(6, source="observed", seeding=SeedingConfig(location_decoys=2))
    memory = EpisodeMemory(config, "recall", encoder, lambda entries, ages, timescale: np.ones(len(entries)), TEMPLATE, "drawer")
    frame = runner.reset(7, {})
    placed, target = frame.state.placed(), frame.state.target_name()
    memory.start(frame, np.random.default_rng(0))
    facts = {e.entity: e.value for e in memory.bank.entries if e.type == MemoryType.OBJECT_LOCATION}
    assert {name: facts[name] for name in placed} == {n: f"drawer layer {layer}" for n, layer in placed.items()}
    assert memory.true_slot() >= 0 and memory.bank.entries[memory.true_slot()].entity == target
    memory.start(replace(frame, look_in=np.zeros_like(frame.look_in)), np.random.default_rng(0))  # saw nothing
    assert not {e.entity for e in memory.bank.entries} & set(placed) and memory.true_slot() == -1
    runner.close()


def test_long_term_slots_come_first_and_a_needed_fact_can_be_gone(encoder):
    runner = TaskRunner({"obs_mode": "state_dict", "render_backend": "none", "objects": OBJECT_SETS["train"],
                         "n_objects": 3}, 80, "drawer")
    memory = EpisodeMemory(_long_term(3), "recall", encoder,
                           lambda entries, ages, timescale: np.array([e.timestamp for e in entries], float), TEMPLATE,
                           _household(hearsay_per_episode=1))
    frame = runner.reset(0, {"placement": {"tin": 2, "cube": 1, "box": 3}, "target": "tin"})
    memory.start(frame, np.random.default_rng(0), moved=True)
    assert [e.entity for e in memory.long_term.entries] != [] and len(memory.long_term) == 1  # one hearsay fact
    obs = memory.observation()
    assert obs["memories"].shape == (6, 384) and obs["mask"].tolist() == [1, 0, 0, 1, 0, 0]  # hearsay | holding decoy
    memory.long_term.write(location_memory("tin", 2, 5).with_embedding(encoder.encode_one("the tin is in drawer layer 2.")))
    memory.seen_since_move.add("tin")
    assert memory.true_slot() == 1
    assert [e.text for e in memory.choose(np.array([1, 2, 3]))] == ["the tin is in drawer layer 2.",
                                                                    memory.bank.entries[0].text]  # slot 2 is empty
    assert memory.long_term.entries[1].usage_count == 1
    assert not memory.needed_fact_gone
    for k in range(10):  # later tasks' hearsay, evicted first in first out, pushes the tin's fact out
        memory.t = 10  # each task lasted ten control steps
        memory.start(frame, np.random.default_rng(k))
        if memory.true_slot() == -1:
            break
    assert memory.needed_fact_gone and memory.info(False)["needed_fact_gone"]
    assert all(e.timestamp > 5 for e in memory.long_term.entries)
    runner.close()


def test_what_the_store_kept_is_counted_before_the_glimpse_and_a_refused_sighting_still_counts_as_seen(encoder):
    runner = TaskRunner({"obs_mode": "state_dict", "render_backend": "none", "objects": OBJECT_SETS["train"],
                         "n_objects": 3}, 80, "drawer")
    oldest_first = lambda entries, ages, timescale: -np.array([e.timestamp for e in entries], float)  # refuses every newcomer
    memory = EpisodeMemory(_long_term(2), "recall", encoder, oldest_first, TEMPLATE,
                           _household(hearsay_per_episode=0))
    frame = runner.reset(0, {"placement": {"tin": 2, "cube": 1, "box": 3}, "target": "tin"})
    memory.start(frame, np.random.default_rng(0), moved=True)
    fact = lambda name, layer, t: location_memory(name, layer, t).with_embedding(
        encoder.encode_one(f"the {name} is in drawer layer {layer}."))
    memory._write([fact("tin", 3, 1)])  # seen before the household rearranged: now stale
    memory.start(frame, np.random.default_rng(0), moved=True)
    assert memory.stale_fact_kept and not memory.target_fact_kept and not memory.needed_fact_gone
    memory._write([fact("tin", 2, 2)])  # seen again: the same key is replaced in place
    memory.start(frame, np.random.default_rng(0))
    assert memory.target_fact_kept and not memory.stale_fact_kept
    memory.start(frame, np.random.default_rng(0), moved=True)
    memory.long_term.clear()
    memory._write([fact("sponge", 1, 3), fact("mug", 2, 4), fact("tin", 2, 5)])  # the store is full: tin's refused
    assert "tin" not in {e.entity for e in memory.long_term.entries} and "tin" in memory.seen_since_move
    memory.start(frame, np.random.default_rng(0))
    info = memory.info(False)
    assert info["needed_fact_gone"] and not info["target_fact_kept"] and not info["stale_fact_kept"]
    runner.close()


@pytest.mark.parametrize("glimpses", [1, 2])
def test_a_household_glimpse_writes_what_is_in_the_drawers_looked_into_and_nothing_else(encoder, glimpses):
    runner = TaskRunner({"obs_mode": "state_dict", "render_backend": "none", "objects": OBJECT_SETS["train"],
                         "n_objects": 3}, 80, "drawer")
    memory = EpisodeMemory(_long_term(3), "recall", encoder,
                           lambda entries, ages, timescale: np.array([e.timestamp for e in entries], float), TEMPLATE,
                           _household(hearsay_per_episode=0, glimpses_per_episode=glimpses))
    placement = {"tin": 2, "cube": 1, "box": 3}
    frame = runner.reset(0, {"placement": placement, "target": "tin"})
    seen_layers = set()
    for seed in range(6):
        memory.long_term.clear()
        memory.start(frame, np.random.default_rng(seed), moved=True)
        facts = {e.entity: e.value for e in memory.long_term.entries}
        assert len(facts) == glimpses and all(value == f"drawer layer {placement[name]}" for name, value in facts.items())
        assert memory.seen_since_move == set(facts)
        seen_layers |= {placement[name] for name in facts}
    assert seen_layers == set(LAYERS)  # the drawers are drawn at random
    runner.close()


@pytest.mark.parametrize("unit", ["steps", "tasks"])
def test_ages_count_control_steps_or_tasks_alike_for_the_critic_and_the_observation(encoder, unit):
    runner = TaskRunner({"obs_mode": "state_dict", "render_backend": "none", "objects": OBJECT_SETS["train"],
                         "n_objects": 3}, 80, "drawer")
    scored: list[np.ndarray] = []

    def newest_first(entries, ages, timescale):
        scored.append(np.asarray(ages))
        return -np.asarray(ages, dtype=float)

    memory = EpisodeMemory(_long_term(2, age_unit=unit), "recall", encoder, newest_first, TEMPLATE,
                           _household(hearsay_per_episode=0))
    frame = runner.reset(0, {"placement": {"tin": 2, "cube": 1, "box": 3}, "target": "tin"})
    fact = lambda name, layer: location_memory(name, layer, memory.now).with_embedding(
        encoder.encode_one(f"the {name} is in drawer layer {layer}."))
    memory.start(frame, np.random.default_rng(0), moved=True)
    memory._write([fact("tin", 2)])  # written in the first task at step 0
    memory.t = 10
    memory.start(frame, np.random.default_rng(0))
    memory.t = 4
    memory._write([fact("cube", 1)])  # the second task, step 14 of the household
    memory.t = 7
    expected = {"steps": [17, 3], "tasks": [1, 0]}[unit]
    np.testing.assert_array_equal(memory.observation()["age"][:2], expected)
    memory._write([fact("box", 3)])  # the store is full: the oldest goes, by the ages the scorer was given
    np.testing.assert_array_equal(scored[-1], expected + [0])
    assert [e.entity for e in memory.long_term.entries] == ["box", "cube"]
    runner.close()
