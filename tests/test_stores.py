"""The multi-timescale memory: stores by timescale, each with its own capacity, age unit and eviction rule; the
critic told each memory's store; the layout read from a config and saved with a run."""

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

from sb3_memret.envs.configs import MemoryConfig, split_env_kwargs
from sb3_memret.envs.recall_memory import EpisodeMemory
from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.memory.stores import (StoreSpec, TIMESCALES, age_units, check_stores, store_index, timescale_id,
                                      units_per_timescale)
from sb3_memret.physics.backends import TaskRunner
from sb3_memret.policy.networks import RetentionScorer
from sb3_memret.policy.policy import MemoryRetrievalPolicy
from sb3_memret.policy.ppo import MemRetPPO
from sb3_memret.tasks.drawer.prompts import TEMPLATE
from sb3_memret.training.config import parse_section

NOW_AND_EPISODE = ({"timescale": "now", "capacity": 2}, {"timescale": "episode", "capacity": 4})


def _entry(text: str, kind: MemoryType = MemoryType.OTHER, t: int = 0, dim: int = 384) -> MemoryEntry:
    vector = np.random.default_rng(abs(hash(text)) % 2**32).standard_normal(dim).astype(np.float32)
    return MemoryEntry(kind, text, "is", "x", t, text, vector / np.linalg.norm(vector))


# ------------------------------------------------------------ the layout
def test_a_store_is_checked_and_reads_back_from_its_mapping():
    spec = StoreSpec.from_mapping({"timescale": "lasting", "capacity": 3, "age_unit": "tasks", "retention": "fifo"})
    assert StoreSpec.from_mapping(spec.to_mapping()) == spec
    assert StoreSpec("now", 1).to_mapping() == {"timescale": "now", "capacity": 1, "age_unit": "steps"}
    with pytest.raises(ValueError, match="unknown timescale 'week'; expected one of"):
        StoreSpec("week", 2)
    with pytest.raises(ValueError, match="the now store's capacity must be an integer >= 1, got 0"):
        StoreSpec("now", 0)
    with pytest.raises(ValueError, match="unknown retention rule 'newest'"):
        StoreSpec("now", 2, retention="newest")
    with pytest.raises(ValueError, match=r"unknown keys \['size'\] / missing keys \['capacity'\]"):
        StoreSpec.from_mapping({"timescale": "now", "size": 2})
    with pytest.raises(ValueError, match=r"one store per timescale, but \['now'\] appear more than once"):
        check_stores([{"timescale": "now", "capacity": 1}, {"timescale": "now", "capacity": 2}])
    with pytest.raises(ValueError, match="at least one store"):
        check_stores([])


@pytest.mark.parametrize("layout, routes", [
    (["episode"], {"now": 0, "episode": 0, "lasting": 0}),  # one bank takes every fact
    (["lasting", "episode"], {"now": 1, "episode": 1, "lasting": 0}),  # the household's layout
    (["now", "episode", "lasting"], {"now": 0, "episode": 1, "lasting": 2}),
    (["lasting", "now"], {"now": 1, "episode": 0, "lasting": 0}),  # no episode store: the next longer-lived one
    (["now"], {"now": 0, "episode": 0, "lasting": 0}),
])
def test_each_fact_goes_to_its_timescale_s_store_or_the_nearest_longer_lived(layout, routes):
    stores = check_stores([{"timescale": t, "capacity": 1} for t in layout])
    assert {t: store_index(t, stores) for t in TIMESCALES} == routes


def test_age_units_are_one_when_stores_agree_else_one_per_timescale():
    assert age_units(check_stores(NOW_AND_EPISODE)) == "steps"
    mixed = check_stores([{"timescale": "lasting", "capacity": 2, "age_unit": "tasks"}, {"timescale": "episode",
                                                                                          "capacity": 2}])
    assert age_units(mixed) == {"lasting": "tasks", "episode": "steps"}
    assert units_per_timescale("tasks", ["now", "episode"]) == {"now": "tasks", "episode": "tasks"}
    with pytest.raises(ValueError, match=r"name no unit for the \['now'\] store"):
        units_per_timescale({"episode": "steps"}, ["now", "episode"])


def test_memory_config_derives_the_old_layout_and_refuses_a_mixed_one():
    assert MemoryConfig(5).store_specs == (StoreSpec("episode", 5),)
    household = MemoryConfig(3, 2, "observed", age_unit="tasks")
    assert household.store_specs == (StoreSpec("lasting", 2, "tasks"), StoreSpec("episode", 3, "tasks"))
    assert household.slots == 5 and household.household and household.age_units == "tasks"
    stores = MemoryConfig(stores=NOW_AND_EPISODE)
    assert stores.slots == 6 and not stores.household and stores.store_specs[0] == StoreSpec("now", 2)
    with pytest.raises(ValueError, match="either stores or long_term_capacity"):
        MemoryConfig(long_term_capacity=2, source="observed", stores=NOW_AND_EPISODE)
    with pytest.raises(ValueError, match="long-term store is written from what the robot sees"):
        MemoryConfig(stores=({"timescale": "lasting", "capacity": 2},))


def test_a_config_s_stores_reach_the_env_and_the_critic_and_a_clash_is_refused():
    section = {"n_timesteps": 64, "env_kwargs": {"stores": [{"timescale": "lasting", "capacity": 2, "age_unit": "tasks"},
                                                            {"timescale": "episode", "capacity": 3}],
                                                 "memory_source": "observed", "k": 5}}
    config = parse_section(section, "sb3_memret/DrawerRecall-v0")
    assert config.algo_kwargs()["policy_kwargs"]["age_unit"] == {"lasting": "tasks", "episode": "steps"}
    _, _, memory, _, _ = split_env_kwargs(config.env_kwargs)
    assert memory.store_specs == (StoreSpec("lasting", 2, "tasks"), StoreSpec("episode", 3)) and memory.household
    with pytest.raises(ValueError, match=r"sets stores and \['capacity'\]: each store gives its own"):
        parse_section({**section, "env_kwargs": {**section["env_kwargs"], "capacity": 4}}, "sb3_memret/DrawerRecall-v0")
    with pytest.raises(ValueError, match="k=6 exceeds capacity=5"):
        parse_section({**section, "env_kwargs": {**section["env_kwargs"], "k": 6}}, "sb3_memret/DrawerRecall-v0")
    with pytest.raises(ValueError, match=r"stores=.* is invalid: unknown timescale 'day'"):
        parse_section({"n_timesteps": 64, "env_kwargs": {"stores": [{"timescale": "day", "capacity": 1}]}},
                      "sb3_memret/DrawerRecall-v0")
    with pytest.raises(ValueError, match=r"drop \['age_unit'\], or drop stores"):
        split_env_kwargs({"stores": list(NOW_AND_EPISODE), "age_unit": "tasks"})


# ------------------------------------------------------------ the memory
def _memory(encoder, stores, scorer=None, **config):
    calls = []

    def critic(entries, ages, timescale):
        calls.append(timescale)
        return np.array([e.timestamp for e in entries], float)  # oldest evicted

    config = MemoryConfig(stores=tuple(stores), seeding=SeedingConfig(location_decoys=1, holding_decoys=2), **config)
    return EpisodeMemory(config, "recall", encoder, scorer or critic, TEMPLATE, "drawer"), calls


def test_the_drawer_s_facts_fill_their_own_stores_and_the_observation_names_each_slot_s(encoder):
    runner = TaskRunner({"obs_mode": "state_dict", "render_backend": "none"}, 80, "drawer")
    memory, calls = _memory(encoder, NOW_AND_EPISODE)
    frame = runner.reset(3, {})
    memory.start(frame, np.random.default_rng(0))
    now, episode = memory.stores
    assert [e.type for e in now.entries] == [MemoryType.HOLDING]  # what it holds is of the moment (one fact per key)
    assert {e.type for e in episode.entries} == {MemoryType.OBJECT_LOCATION} and len(episode) == 2  # fact + decoy
    obs = memory.observation()
    assert obs["store_ids"].tolist() == [timescale_id("now")] * 2 + [timescale_id("episode")] * 4
    assert obs["mask"].tolist() == [1, 0, 1, 1, 0, 0]
    assert memory.true_slot() >= 2  # the cube's fact is in the episode store
    for t in range(1, 6):  # a flood of failures seen evicts within the now store, oldest first, and nowhere else
        memory._write(memory._encoded([_entry(f"the grasp of thing {t} failed.", MemoryType.FAILURE, 100 + t)]))
    assert [e.text for e in now.entries] == ["the grasp of thing 4 failed.", "the grasp of thing 5 failed."]
    assert len(episode) == 2 and memory.true_slot() >= 2 and not memory.true_evicted
    assert set(calls) == {timescale_id("now")}  # the critic was told which store it scored
    memory.start(frame, np.random.default_rng(1))  # neither store outlives the episode
    assert all(e.timestamp == 0 for store in memory.stores for e in store.entries)
    runner.close()


def test_each_store_evicts_by_its_own_rule_and_counts_ages_in_its_own_unit(encoder):
    runner = TaskRunner({"obs_mode": "state_dict", "render_backend": "none"}, 80, "drawer")
    stores = [{"timescale": "now", "capacity": 1, "retention": "fifo"}, {"timescale": "episode", "capacity": 4}]
    memory, calls = _memory(encoder, stores, retention="prior")
    memory.start(runner.reset(3, {}), np.random.default_rng(0))
    assert calls == []  # the now store by FIFO, the episode store by the prior: the critic was never asked
    memory._write(memory._encoded([_entry("the grasp of the late thing failed.", MemoryType.FAILURE, 50)]))
    assert [e.text for e in memory.stores[0].entries] == ["the grasp of the late thing failed."]  # FIFO: the newest stays
    memory.t = 80
    assert memory.ages(memory.stores[0].entries, "steps").tolist() == [30.0]  # written at 50, now 80
    assert memory.ages(memory.stores[0].entries, "tasks").tolist() == [0.0]
    runner.close()


# ------------------------------------------------------------ the critic
def test_the_critic_reads_each_memory_s_store_and_scales_its_age_by_the_store_s_unit():
    torch.manual_seed(0)
    critic = RetentionScorer(age_unit={"lasting": "tasks", "episode": "steps"}, stores=True)
    entries = [_entry("a"), _entry("b")]
    ages = np.array([2.0, 2.0], np.float32)
    lasting, episode = (critic.score_entries(entries, ages, timescale_id(t)) for t in ("lasting", "episode"))
    assert not np.allclose(lasting, episode)  # the same memories weigh differently by store
    features = critic._features(torch.zeros(1, 2, 384), torch.zeros(1, 2), torch.full((1, 2), 2.0), torch.zeros(1, 2),
                                torch.tensor([[timescale_id("lasting"), timescale_id("episode")]]))
    assert features[0, :, 384 + 32].tolist() == pytest.approx([2.0, 0.02])  # tasks at scale 1, steps at 100
    with pytest.raises(ValueError, match="pass store_ids"):
        critic(torch.zeros(1, 2, 384), torch.zeros(1, 2), torch.zeros(1, 2), torch.zeros(1, 2))
    with pytest.raises(ValueError, match="without a store embedding was asked to score a store"):
        RetentionScorer().score_entries(entries, ages, timescale_id("now"))
    with pytest.raises(ValueError, match="need a memory of several stores"):
        RetentionScorer(age_unit={"episode": "steps"})


def test_a_run_with_stores_trains_on_the_real_simulator_saves_and_loads(encoder, tmp_path):
    stores = [{"timescale": "now", "capacity": 2, "retention": "fifo"}, {"timescale": "episode", "capacity": 4}]
    venv = make_recall_vec_env(1, {"stores": stores, "encoder": encoder, "max_control_steps": 16}, seed=0)
    try:
        assert venv.observation_space["store_ids"].shape == (6,)
        model = MemRetPPO(MemoryRetrievalPolicy, venv, n_steps=8, batch_size=8, n_epochs=1, seed=0)
        assert model.policy.retention.store_embedding is not None
        before = model.policy.retention.store_embedding.weight.detach().clone()
        model.learn(16)
        assert not torch.equal(before, model.policy.retention.store_embedding.weight)  # the value loss reaches it
        assert venv.unwrapped.retention is not None  # the critic evicts in the env's episode store
        model.save(tmp_path / "m.zip")
        loaded = PPO.load(tmp_path / "m.zip", device="cpu")
        obs = venv.reset()
        obs_t, _ = model.policy.obs_to_tensor(obs)
        assert loaded.policy.predict_values(obs_t).item() == pytest.approx(model.policy.predict_values(obs_t).item())
        with pytest.raises(ValueError, match="reads ages in 'tasks'"):
            venv.unwrapped.set_retention_weights(model.policy.retention_state_dict(), age_unit="tasks")
    finally:
        venv.close()


def test_event_decoys_arrive_while_the_task_goes_on_and_flood_one_bank_but_not_the_episode_store(encoder):
    from dataclasses import replace

    runner = TaskRunner({"obs_mode": "state_dict", "render_backend": "none"}, 80, "drawer")
    frame = runner.reset(3, {})
    seeding = SeedingConfig(location_decoys=2, holding_decoys=0, event_every=8)
    one_bank = EpisodeMemory(MemoryConfig(4, retention="fifo", seeding=seeding), "recall", encoder, None, TEMPLATE,
                             "drawer")
    stores = EpisodeMemory(MemoryConfig(stores=({"timescale": "now", "capacity": 1, "retention": "fifo"},
                                                {"timescale": "episode", "capacity": 3, "retention": "fifo"}),
                                        seeding=seeding), "recall", encoder, None, TEMPLATE, "drawer")
    for memory in (one_bank, stores):
        memory.start(frame, np.random.default_rng(0))
        assert memory.facts_in_bank()
        for _ in range(6):  # 48 control steps in chunks of 8: six things seen out on the table
            memory.observe(replace(frame, steps=8))
    events = [e for store in stores.stores for e in store.entries if e.value == "outside"]
    assert [e.timestamp for e in events] == [48] and stores.stores[0].entries == events  # the newest, in its store
    assert events[0].text.endswith(" is out of the drawers.")
    assert stores.facts_in_bank() and not stores.true_evicted
    assert not one_bank.facts_in_bank() and one_bank.true_evicted  # first in, first out: the cue's fact went first
    with pytest.raises(ValueError, match="event_every must be an integer >= 0"):
        SeedingConfig(event_every=-8)
    runner.close()


def test_a_task_that_words_no_event_decoys_refuses_them_at_once(encoder):
    with pytest.raises(ValueError, match="words no event decoys"):
        EpisodeMemory(MemoryConfig(4, seeding=SeedingConfig(event_every=8)), "recall", encoder, None, TEMPLATE,
                      "RememberColor3-VLA-v0")


def test_one_rule_swapped_in_reaches_every_store():
    from sb3_memret.envs.configs import with_retention

    kwargs = with_retention({"stores": [{"timescale": "now", "capacity": 2, "retention": "lru"},
                                        StoreSpec("episode", 3)], "k": 1}, "fifo")
    assert kwargs["retention"] == "fifo" and [s["retention"] for s in kwargs["stores"]] == ["fifo", "fifo"]
    assert with_retention({"capacity": 4}, "prior") == {"capacity": 4, "retention": "prior"}
    with pytest.raises(ValueError, match="unknown retention rule 'newest'"):
        with_retention({}, "newest")
