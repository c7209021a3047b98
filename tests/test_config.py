from pathlib import Path

import pytest
import yaml

from sb3_memret.training.config import load_config, parse_section

ZOO = Path(__file__).resolve().parents[1] / "zoo_configs" / "memret_ppo.yml"
ENV_ID = "sb3_memret/DrawerRecall-v0"


def test_shipped_config_has_the_paper_hyperparameters_but_its_learning_rate():
    cfg = load_config(ZOO, ENV_ID)
    assert cfg.ppo["gamma"] == 0.97 and cfg.ppo["clip_range"] == 0.2 and cfg.ppo["n_epochs"] == 4
    assert cfg.ppo["ent_coef"] == 0.001 and cfg.ppo["vf_coef"] == 0.5
    # the paper's 3e-4 never clipped a sample in the camera main job's rounds: ten times it, falling to 0
    schedule = cfg.algo_kwargs()["learning_rate"]
    assert cfg.ppo["learning_rate"] == "lin_3e-3" and (schedule(1.0), schedule(0.5), schedule(0.0)) == (3e-3, 1.5e-3, 0)
    assert cfg.policy_kwargs == {"temperature": 0.5, "exploration": "episode"}
    assert cfg.env_kwargs["capacity"] == 6 and cfg.env_kwargs["k"] == 1
    kwargs = cfg.algo_kwargs()
    assert "n_timesteps" not in kwargs and "n_envs" not in kwargs and kwargs["policy_kwargs"] == cfg.policy_kwargs


def test_set_retriever_config_differs_from_the_default_only_in_its_retriever():
    default, variant = load_config(ZOO, ENV_ID), load_config(ZOO.with_name("memret_ppo_set.yml"), ENV_ID)
    assert variant.policy_kwargs == {**default.policy_kwargs, "retriever": "set"}
    assert (variant.ppo, variant.env_kwargs) == (default.ppo, default.env_kwargs)


def test_benchmark_configs_differ_from_the_default_only_in_what_they_name():
    """... and in their length, round size, evaluations and learning rate: instruction-conditioned retrieval of three
    objects takes more decisions, in rounds of more episodes (with rounds of ~3 the retriever could settle on a safe
    memory), at the paper's learning rate; the main job's ten-fold one is for its 10-minute budget."""
    default = load_config(ZOO, ENV_ID)
    objects = load_config(ZOO.with_name("memret_ppo_objects.yml"), ENV_ID)
    budget = {key: default.ppo[key] for key in ("eval_episodes", "eval_every", "initial_eval_episodes",
                                                 "final_eval_episodes", "learning_rate")
              if key in default.ppo}  # the main job's
    assert {key: value for key, value in objects.ppo.items() if key != "initial_eval_episodes"} | {
        "n_timesteps": default.n_timesteps, "n_steps": default.ppo["n_steps"], **budget} == default.ppo
    assert objects.ppo["learning_rate"] == 3e-4
    assert objects.ppo["n_steps"] > default.ppo["n_steps"]
    assert objects.policy_kwargs == default.policy_kwargs
    assert objects.env_kwargs == {**default.env_kwargs, "objects": "train", "n_objects": 3, "location_decoys": 2,
                                  "holding_decoys": 2}
    objects_set = load_config(ZOO.with_name("memret_ppo_objects_set.yml"), ENV_ID)
    assert objects_set.policy_kwargs == {**default.policy_kwargs, "retriever": "set"}
    assert (objects_set.ppo, objects_set.env_kwargs) == (objects.ppo, objects.env_kwargs)
    observed = load_config(ZOO.with_name("memret_ppo_observed.yml"), ENV_ID)
    assert observed.env_kwargs == {**objects.env_kwargs, "memory_source": "observed"}
    assert (observed.ppo, observed.policy_kwargs) == (objects.ppo, objects.policy_kwargs)


@pytest.mark.parametrize(
    "section,message",
    [
        ({"n_timesteps": 10, "gama": 0.9}, "unknown key 'gama'; accepted keys are"),
        ({"n_timesteps": 10, "gamma": 1.5}, r"gamma=1.5 is invalid; expected a number in \(0, 1\]"),
        ({"n_timesteps": 0}, "n_timesteps=0 is invalid; expected an integer >= 1"),
        ({"n_timesteps": 10, "eval_every": 0}, "eval_every=0 is invalid; expected an integer >= 1"),
        ({"n_timesteps": 10, "n_steps": True}, "n_steps=True is invalid"),
        ({"gamma": 0.9}, "must set n_timesteps"),
        ({"n_timesteps": 10, "env_kwargs": {"mode": "guess"}}, "mode='guess' is invalid; expected one of 'recall'"),
        ({"n_timesteps": 10, "env_kwargs": {"k": 3, "capacity": 2}}, "k=3 exceeds capacity=2"),
        ({"n_timesteps": 10, "policy_kwargs": {"tau": 0.5}}, "unknown key 'tau'"),
        ({"n_timesteps": 10, "policy_kwargs": {"retriever": "gnn"}}, "retriever='gnn' is invalid; expected one of 'mlp'"),
        ({"n_timesteps": 10, "env_kwargs": {"objects": "kitchen"}}, "objects='kitchen' is invalid; expected one of the "
                                                                    "object sets"),
        ({"n_timesteps": 10, "env_kwargs": {"n_objects": 4}}, r"n_objects=4 is invalid; expected an integer in \[1, 3\]"),
        ({"n_timesteps": 10, "env_kwargs": {"memory_source": "oracle"}}, "memory_source='oracle' is invalid"),
        ({"n_timesteps": 10, "env_kwargs": {"observe_potential": "yes"}}, "observe_potential='yes' is invalid; "
                                                                         "expected true or false"),
        ({"n_timesteps": 10, "env_kwargs": {"observe_potential": 1}}, "observe_potential=1 is invalid"),
        ({"n_timesteps": 10, "env_kwargs": {"age_unit": "seconds"}}, r"age_unit='seconds' is invalid; expected one of "
                                                                     r"\['steps', 'tasks'\]"),
    ],
)
def test_bad_configs_are_rejected_with_the_key_and_the_accepted_values(section, message):
    with pytest.raises(ValueError, match=message):
        parse_section(section, ENV_ID)


def test_a_section_may_set_its_evaluations_which_are_not_ppo_arguments():
    config = parse_section({"n_timesteps": 10, "eval_episodes": 30, "eval_every": 10, "initial_eval_episodes": 8},
                           ENV_ID)
    assert (config.eval_episodes, config.eval_every, config.initial_eval_episodes) == (30, 10, 8)
    assert not {"eval_episodes", "eval_every", "initial_eval_episodes"} & set(config.algo_kwargs())
    plain = parse_section({"n_timesteps": 10}, ENV_ID)
    assert (plain.eval_episodes, plain.eval_every, plain.initial_eval_episodes) == (50, 5, None)
    with pytest.raises(ValueError, match="initial_eval_episodes=0 is invalid; expected an integer >= 1"):
        parse_section({"n_timesteps": 10, "initial_eval_episodes": 0}, ENV_ID)
    with pytest.raises(ValueError, match="initial_eval_episodes=60 exceeds eval_episodes=50"):
        parse_section({"n_timesteps": 10, "initial_eval_episodes": 60}, ENV_ID)
    final = parse_section({"n_timesteps": 10, "eval_episodes": 8, "final_eval_episodes": 24}, ENV_ID)
    assert final.final_eval_episodes == 24 and "final_eval_episodes" not in final.algo_kwargs()
    assert plain.final_eval_episodes is None
    with pytest.raises(ValueError, match="final_eval_episodes=4 is below eval_episodes=8"):
        parse_section({"n_timesteps": 10, "eval_episodes": 8, "final_eval_episodes": 4}, ENV_ID)


@pytest.mark.parametrize("bad", ["lin_", "lin_-1e-3", "lin_abc", "lin_inf", "cos_3e-3", "3e-3", 0, -1e-3])
def test_a_learning_rate_is_a_positive_number_or_a_linear_schedule_from_one(bad):
    with pytest.raises(ValueError, match=r"learning_rate=.* is invalid; expected a number > 0, or 'lin_<number>'"):
        parse_section({"n_timesteps": 10, "learning_rate": bad}, ENV_ID)


def test_a_linear_learning_rate_falls_as_ppo_trains_and_survives_save_and_load(tmp_path):
    from stable_baselines3.common.vec_env import DummyVecEnv

    from sb3_memret.policy.policy import MemoryRetrievalPolicy
    from sb3_memret.policy.ppo import MemRetPPO
    from toy_bank import ToyBankEnv

    config = parse_section({"n_timesteps": 64, "n_steps": 16, "batch_size": 8, "learning_rate": "lin_1e-3"}, ENV_ID)
    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), seed=0, **config.algo_kwargs())
    seen = []
    model._update_learning_rate = lambda optimizers: seen.append(model.lr_schedule(model._current_progress_remaining))
    model.learn(64)
    assert seen == pytest.approx([7.5e-4, 5e-4, 2.5e-4, 0.0])  # SB3 counts a round's progress before its update
    model.save(tmp_path / "model.zip")
    assert MemRetPPO.load(tmp_path / "model.zip").lr_schedule(0.5) == pytest.approx(5e-4)


def test_the_policy_reads_ages_in_the_unit_the_env_counts_them_in():
    assert "age_unit" not in parse_section({"n_timesteps": 10}, ENV_ID).algo_kwargs()["policy_kwargs"]  # steps
    config = parse_section({"n_timesteps": 10, "env_kwargs": {"age_unit": "tasks"}}, ENV_ID)
    assert config.algo_kwargs()["policy_kwargs"]["age_unit"] == "tasks"


def test_missing_env_section_and_file(tmp_path):
    path = tmp_path / "c.yml"
    path.write_text(yaml.safe_dump({"Other-v0": {"n_timesteps": 1}}))
    with pytest.raises(ValueError, match=r"no section for env id 'sb3_memret/DrawerRecall-v0'; the file has \['Other-v0'\]"):
        load_config(path, ENV_ID)
    with pytest.raises(FileNotFoundError, match="no config file at"):
        load_config(tmp_path / "missing.yml", ENV_ID)
