"""MemoryRetrievalPolicy and MemRetPPO on a small synthetic bank task the test makes."""

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_memret.policy.policy import MemoryRetrievalPolicy, saved_retriever
from sb3_memret.policy.ppo import MemRetPPO
from toy_bank import ToyBankEnv


def greedy_accuracy(model, episodes=200, empty_slots=0):
    env, hits = ToyBankEnv(empty_slots), 0
    for seed in range(10_000, 10_000 + episodes):
        obs, info = env.reset(seed=seed)
        action, _ = model.predict(obs, deterministic=True)
        hits += int(action[0]) == info["true_slot"]
    return hits / episodes


def make_model(seed=0, **kwargs):
    return MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=64, batch_size=64, seed=seed, **kwargs)


def test_forward_shapes_masking_and_greedy():
    model = make_model()
    env = ToyBankEnv(empty_slots=2)
    obs, _ = env.reset(seed=0)
    obs_t, _ = model.policy.obs_to_tensor(obs)
    actions, values, log_prob = model.policy(obs_t)
    assert actions.shape == (1, 1) and values.shape == (1, 1) and log_prob.shape == (1,)
    for _ in range(50):
        assert model.policy(obs_t)[0].item() < 4  # empty slots are never chosen
    scores = model.policy.scores(model.policy.extract_features(obs_t))
    greedy, _ = model.predict(obs, deterministic=True)
    assert greedy[0] == scores[0, :4].argmax().item()


def test_value_is_mean_keep_score_over_valid_slots():
    model = make_model()
    obs, _ = ToyBankEnv(empty_slots=3).reset(seed=1)
    obs_t, _ = model.policy.obs_to_tensor(obs)
    f = model.policy.extract_features(obs_t)
    keep = model.policy.retention(f["memories"], f["type_ids"].long(), f["age"], f["usage"])
    assert model.policy.predict_values(obs_t).item() == pytest.approx(keep[0, :3].mean().item(), rel=1e-5)


def test_an_observed_potential_is_subtracted_from_the_value_and_survives_save_and_load(tmp_path):
    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([lambda: ToyBankEnv(potential=True)]), n_steps=64, seed=0)
    assert model.policy.potential_baseline and not make_model().policy.potential_baseline
    obs, _ = ToyBankEnv(potential=True).reset(seed=2)
    obs_t, _ = model.policy.obs_to_tensor(obs)
    f = model.policy.extract_features(obs_t)
    keep = model.policy.retention(f["memories"], f["type_ids"].long(), f["age"], f["usage"]).mean()
    assert obs["potential"][0] > 0
    assert model.policy.predict_values(obs_t).item() == pytest.approx(keep.item() - obs["potential"][0], rel=1e-5)
    model.save(tmp_path / "m.zip")
    loaded = PPO.load(tmp_path / "m.zip", device="cpu")
    assert loaded.policy.potential_baseline
    assert loaded.policy.predict_values(obs_t).item() == pytest.approx(model.policy.predict_values(obs_t).item())


def test_the_age_unit_sets_the_critics_age_scale_and_survives_save_and_load(tmp_path):
    model = make_model(policy_kwargs={"age_unit": "tasks"})
    assert set(model.policy.retention.age_scales.tolist()) == {1.0}
    assert set(make_model().policy.retention.age_scales.tolist()) == {100.0}
    model.save(tmp_path / "m.zip")
    assert PPO.load(tmp_path / "m.zip", device="cpu").policy.age_unit == "tasks"
    with pytest.raises(ValueError, match="unknown age unit 'days'; expected one of"):
        make_model(policy_kwargs={"age_unit": "days"})


@pytest.mark.parametrize("retriever", ["mlp", "set"])
def test_save_and_plain_ppo_load_give_identical_greedy_actions(tmp_path, retriever):
    model = make_model(policy_kwargs={"retriever": retriever})
    model.learn(128)
    path = tmp_path / "model.zip"
    model.save(path)
    loaded = PPO.load(path)
    assert isinstance(loaded.policy, MemoryRetrievalPolicy) and loaded.policy.retriever_kind == retriever
    env = ToyBankEnv()
    for seed in range(20):
        obs, _ = env.reset(seed=seed)
        np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])


def test_retention_weights_are_pushed_each_rollout():
    model = make_model()
    model.learn(192)  # three rollouts of 64 steps
    env = model.get_env().envs[0]
    assert len(env.received_weights) == 3
    for key, value in model.policy.retention_state_dict().items():
        assert env.received_weights[0][key].shape == value.shape


@pytest.mark.parametrize("retriever", ["mlp", "set"])
def test_retrieval_is_learned_from_reward_alone(retriever):
    torch.manual_seed(0)
    model = make_model(seed=0, policy_kwargs={"retriever": retriever})
    before = greedy_accuracy(model)
    model.learn(64 * 30)
    after = greedy_accuracy(model)
    assert before < 0.5
    assert after >= 0.9, (before, after)


def test_set_and_mlp_runs_of_one_seed_share_critic_and_first_rollout():
    """A paired comparison: same seed, same critic weights, and the same first rollout (the context head is
    zero until the first update)."""
    critics, actions = [], []
    for kind in ("mlp", "set"):  # each built and run in turn: both draw from the global stream
        model = make_model(seed=5, policy_kwargs={"retriever": kind})
        critics.append([p.detach().clone() for p in model.policy.retention.parameters()])
        model.learn(64)  # one rollout, then an update
        actions.append(model.rollout_buffer.actions.copy())
    for a, b in zip(*critics):
        torch.testing.assert_close(a, b)
    np.testing.assert_array_equal(*actions)
    assert len(np.unique(actions[0])) > 1  # the rollout explored, so matching draws mean something


def test_the_set_retrievers_attention_learns_at_its_own_rate_through_schedules_and_save(tmp_path):
    """Per-memory path at the retriever's rate, attention and context head at CONTEXT_LR_SCALE of it (or the
    given scale), the critic at the full rate; a learning-rate schedule keeps the ratios and a saved model
    keeps the scale."""
    model = make_model(policy_kwargs={"retriever": "set", "retriever_lr_scale": 0.5}, learning_rate=lambda p: 1e-3 * (1 + p))
    groups = model.policy.optimizer.param_groups
    context = {id(p) for p in model.policy.retriever.context_parameters()}
    assert [{id(p) for p in group["params"]} == context for group in groups] == [False, True, False]
    model.learn(128)  # two rollouts: the schedule has moved the rate
    base = groups[2]["lr"]
    assert 1e-3 <= base < 2e-3  # the schedule moved it from 2e-3
    assert [group["lr"] for group in groups] == pytest.approx([0.5 * base, 0.05 * base, base])
    path = tmp_path / "set.zip"
    model.save(path)
    assert PPO.load(path).policy.context_lr_scale is None
    scaled = make_model(policy_kwargs={"retriever": "set", "context_lr_scale": 0.0})
    assert scaled.policy.optimizer.param_groups[1]["lr"] == 0.0
    scaled.save(path)
    assert PPO.load(path).policy.context_lr_scale == 0.0
    with pytest.raises(ValueError, match="context_lr_scale=0.2 applies to the set retriever's attention only"):
        make_model(policy_kwargs={"context_lr_scale": 0.2})
    with pytest.raises(ValueError, match="context_lr_scale must be >= 0"):
        make_model(policy_kwargs={"retriever": "set", "context_lr_scale": -1})


def test_an_unknown_retriever_is_refused():
    with pytest.raises(ValueError, match=r"unknown retriever 'gnn'; expected one of \['mlp', 'set'\]"):
        make_model(policy_kwargs={"retriever": "gnn"})


def test_a_saved_retriever_is_read_whole_and_another_kind_or_size_is_refused(tmp_path):
    trained = make_model(seed=1)
    trained.learn(64 * 2)
    trained.save(tmp_path / "trained.zip")
    fresh = make_model(seed=2)
    fresh.policy.retriever.load_state_dict(saved_retriever(tmp_path / "trained.zip"))
    for key, value in trained.policy.retriever.state_dict().items():
        torch.testing.assert_close(fresh.policy.retriever.state_dict()[key], value)
    assert not torch.equal(fresh.policy.retention.net[0].weight, trained.policy.retention.net[0].weight)
    with pytest.raises(ValueError, match=r"holds a 'mlp' retriever of hidden size 128; this run's is 'set'"):
        saved_retriever(tmp_path / "trained.zip", kind="set")
    with pytest.raises(ValueError, match=r"this run's is 'mlp' of hidden size 64"):
        saved_retriever(tmp_path / "trained.zip", hidden=64)


class LongBankEnv(ToyBankEnv):
    """The toy bank held for ``length`` decisions per episode; it records each episode's retrievals."""

    def __init__(self, length=4):
        super().__init__()
        self.length, self.episodes = length, []

    def reset(self, *, seed=None, options=None):
        self.t = 0
        self.episodes.append([])
        return super().reset(seed=seed, options=options)

    def step(self, action):
        obs, reward, _, truncated, info = super().step(action)
        self.t += 1
        self.episodes[-1].append(int(action[0]))
        return obs, reward, self.t >= self.length, truncated, info


@pytest.mark.parametrize("exploration", ["episode", "decision"])
def test_episode_exploration_keeps_an_episodes_retrievals_and_draws_anew_for_the_next(exploration):
    envs = DummyVecEnv([LongBankEnv, LongBankEnv])
    model = MemRetPPO(MemoryRetrievalPolicy, envs, n_steps=8, batch_size=16, seed=0, learning_rate=1e-9,
                      policy_kwargs={"exploration": exploration})
    model.learn(8 * 2 * 6)
    episodes = [e for env in envs.envs for e in env.unwrapped.episodes if len(e) == 4]
    assert len(episodes) >= 20
    constant = sum(len(set(e)) == 1 for e in episodes)
    if exploration == "episode":  # the scores barely move (lr 1e-9), so each episode keeps its draw
        assert constant == len(episodes)
        assert len({e[0] for e in episodes}) > 2  # ... and the next episode draws again
    else:  # near-uniform fresh draws: 4 in a row agree 1/6**3 of the time
        assert constant <= 2
    assert model.policy.episode_noise is None  # outside collection every draw is fresh


def test_an_episode_draw_is_exactly_plackett_luce():
    model = make_model(policy_kwargs={"exploration": "episode"})
    obs, _ = ToyBankEnv().reset(seed=3)
    obs_t, _ = model.policy.obs_to_tensor(obs)
    with torch.no_grad():
        model.policy.retriever.net[-1].bias.zero_()
        model.policy.retriever.net[-1].weight.mul_(200.0)  # a peaked distribution, so a wrong sampler shows
        probs = torch.softmax(model.policy.get_distribution(obs_t).logits, -1)[0]
        counts = torch.zeros(6)
        for _ in range(4000):
            model.policy.redraw_noise(1)
            counts[model.policy(obs_t)[0].item()] += 1
    model.policy.episode_noise = None
    assert torch.allclose(counts / 4000, probs, atol=0.03), (counts / 4000, probs)
    assert 0.3 < probs.max() < 0.8  # neither uniform nor argmax: the check above has teeth


def test_exploration_survives_save_and_load_and_unknown_kinds_are_refused(tmp_path):
    model = make_model(policy_kwargs={"exploration": "episode"})
    model.learn(64)
    model.save(tmp_path / "m.zip")
    assert PPO.load(tmp_path / "m.zip").policy.exploration == "episode"
    with pytest.raises(ValueError, match="unknown exploration 'sticky'"):
        make_model(policy_kwargs={"exploration": "sticky"})
