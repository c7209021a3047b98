"""evaluate_retrieval: episode accounting, reproducibility and the retrieval metrics."""

import math

import numpy as np
import pytest
import torch
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_memret.evaluation.retrieval import evaluate_retrieval
from sb3_memret.policy.policy import MemoryRetrievalPolicy
from sb3_memret.policy.ppo import MemRetPPO
from toy_bank import CAP, ToyBankEnv


def make_model(n_envs=1):
    return MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv] * n_envs), n_steps=64, batch_size=64, seed=0)


def uniform(model):
    """Zero the retriever's last layer: every slot scores the same."""
    last = [m for m in model.policy.retriever.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
    return model


def test_counts_every_episode_once_over_several_envs():
    model = make_model()
    venv = DummyVecEnv([ToyBankEnv] * 3)
    seen = []
    report = evaluate_retrieval(model, venv, n_episodes=10, seed=5, on_episode=seen.append)
    assert report.episodes == len(seen) == 10
    assert report.decisions == 10  # one decision per toy episode, the true memory always present
    assert [episode["decisions"] for episode in seen] == [1] * 10
    assert sum(report.episodes_per_group.values()) == 10
    assert set(report.success) >= {"overall"}


def test_same_seed_same_report():
    model = make_model()
    venv = DummyVecEnv([ToyBankEnv] * 2)
    first = evaluate_retrieval(model, venv, 12, seed=3).to_dict()
    second = evaluate_retrieval(model, venv, 12, seed=3).to_dict()
    for key in ("greedy_accuracy", "success", "episodes_per_group", "mean_return"):
        assert first[key] == second[key]


def test_uniform_policy_metrics():
    model = uniform(make_model())
    venv = DummyVecEnv([ToyBankEnv])
    report = evaluate_retrieval(model, venv, n_episodes=60, seed=0, samples=200)
    assert report.entropy == pytest.approx(math.log(CAP), abs=1e-5)
    assert report.sampled_fraction == pytest.approx(1 / CAP, abs=0.03)
    hits = []  # replay the same held-out episodes by hand with the greedy action
    venv.seed(0)
    obs = venv.reset()
    for _ in range(60):
        action, _ = model.predict(obs, deterministic=True)
        obs, _, _, infos = venv.step(action)
        hits.append([int(action[0, 0])] == infos[0]["decision_true_slots"])
    assert report.greedy_accuracy == pytest.approx(np.mean(hits))
    assert report.success["overall"] == report.greedy_accuracy  # the toy succeeds exactly on a hit
    assert report.mean_return == pytest.approx(report.greedy_accuracy)


def test_trained_policy_scores_high():
    torch.manual_seed(0)
    model = make_model()
    model.learn(64 * 30)
    report = evaluate_retrieval(model, DummyVecEnv([ToyBankEnv]), 100, seed=1)
    assert report.greedy_accuracy >= 0.9
    assert report.entropy < math.log(CAP) - 0.2
    assert report.sampled_fraction > 1 / CAP + 0.1


def test_rejects_bad_episode_count():
    with pytest.raises(ValueError, match="n_episodes"):
        evaluate_retrieval(make_model(), DummyVecEnv([ToyBankEnv]), 0)


def test_the_models_retention_critic_is_pushed_before_evaluating():
    """Eviction during evaluation is the model's own critic's, as during training (not the type prior)."""
    model = make_model()
    venv = DummyVecEnv([ToyBankEnv] * 2)
    evaluate_retrieval(model, venv, 2, seed=0)
    expected = model.policy.retention_state_dict()
    for env in venv.envs:
        pushed, = env.received_weights
        assert pushed.keys() == expected.keys() and all(torch.equal(pushed[k], expected[k]) for k in expected)


def test_a_report_round_trips_and_reads_runs_saved_with_layer_groups():
    from sb3_memret.evaluation.retrieval import RetrievalReport

    report = RetrievalReport(episodes=4, decisions=8, greedy_accuracy=0.5, sampled_fraction=0.4, entropy=1.0,
                             success={"overall": 0.5, "red": 1.0, "blue": 0.0}, episodes_per_group={"red": 2, "blue": 2})
    assert RetrievalReport.from_dict(report.to_dict()) == report
    old = {**report.to_dict(), "episodes_per_layer": {"1": 4}}
    del old["episodes_per_group"]
    assert RetrievalReport.from_dict(old).episodes_per_group == {"1": 4}
