"""Retrieval credit and the keep-score calibration it drives: what each memory earned, and the critic ranking by it."""

import numpy as np
import pytest
import torch
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_memret.policy.credit import calibration_loss, retrieval_credit
from sb3_memret.policy.policy import MemoryRetrievalPolicy
from sb3_memret.policy.ppo import MemRetPPO
from toy_bank import ToyBankEnv


def test_credit_follows_a_memory_across_slots_and_stops_at_its_episodes_end():
    a, b, c, d = (np.full(4, v, np.float32) for v in (1, 2, 3, 4))
    # one env, 4 decisions, 3 slots; memory a moves from slot 0 to slot 2 at t = 1; an episode starts at t = 3
    memories = np.array([[[a, b, c]], [[b, c, a]], [[b, c, a]], [[d, b, c]]])
    mask = np.ones((4, 1, 3), np.float32)
    actions = np.array([[[1]], [[2]], [[0]], [[0]]])
    advantages = np.array([[-1.0], [2.0], [1.0], [5.0]])
    starts = np.array([[1], [0], [0], [1]], np.float32)
    credit = retrieval_credit(memories, mask, actions, advantages, starts, discount=0.5)
    # t=2: b retrieved with advantage 1; t=1: a retrieved with 2, b's 1 discounted; t=0: b's negative advantage
    # earns nothing, a (slot 0 then) carries 2 * 0.5, b carries 1 * 0.25; t=3 is the next episode's
    np.testing.assert_allclose(credit[2, 0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(credit[1, 0], [0.5, 0.0, 2.0])
    np.testing.assert_allclose(credit[0, 0], [1.0, 0.25, 0.0])
    np.testing.assert_allclose(credit[3, 0], [5.0, 0.0, 0.0])


def test_empty_slots_earn_nothing():
    memories = np.zeros((1, 1, 3, 4), np.float32)
    memories[0, 0, 0] = 1.0
    credit = retrieval_credit(memories, np.array([[[1, 0, 0]]], np.float32), np.array([[[1]]]), np.array([[3.0]]),
                              np.array([[1]], np.float32), 0.9)
    np.testing.assert_allclose(credit[0, 0], [0.0, 0.0, 0.0])


def test_the_calibration_loss_ranks_by_credit_and_leaves_the_mean_to_the_value_loss():
    credit = torch.tensor([[0.0, 3.0, 1.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    mask = torch.tensor([[True, True, True, False], [True, True, False, False]])
    scores = torch.zeros(2, 4, requires_grad=True)
    loss = calibration_loss(scores, credit, mask)
    assert torch.allclose(calibration_loss(scores.detach() + 7.0, credit, mask), loss.detach())  # shift-blind
    loss.backward()
    grad = scores.grad
    # descent moves the softmax towards the credit shares: the most credited memory up, the uncredited one down
    assert grad[0, 1] < 0 < grad[0, 0] and grad[0, 1] < grad[0, 2] < grad[0, 0]
    assert grad[0, 3] == 0 and (grad[1] == 0).all()  # an empty slot, a bank with no credit: untouched
    assert calibration_loss(scores, torch.zeros(2, 4), mask).item() == 0.0


def true_first_rate(model, episodes=100):
    env, first = ToyBankEnv(), 0
    for seed in range(20_000, 20_000 + episodes):
        obs, info = env.reset(seed=seed)
        obs_t, _ = model.policy.obs_to_tensor(obs)
        with torch.no_grad():
            keep = model.policy.retention(obs_t["memories"], obs_t["type_ids"], obs_t["age"], obs_t["usage"])[0]
        first += int(keep.argmax()) == info["true_slot"]
    return first / episodes


@pytest.mark.parametrize("calibration_coef", [0.0, 1.0])
def test_a_calibrated_critic_keeps_the_memory_retrievals_earn_from(calibration_coef):
    """On the toy bank only retrieving the true memory pays. With the value loss off, the keep-scores learn
    from calibration alone: it puts the true memory first; without it they never rank it first."""
    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=64, batch_size=32, seed=0,
                      calibration_coef=calibration_coef, vf_coef=0.0)
    model.learn(64 * 8)
    assert (true_first_rate(model) > 0.8) == (calibration_coef > 0)


def test_calibration_trains_the_ranking_head_and_never_the_value():
    """With the value loss off, the value head (the advantages' baseline) ends where it ends without
    calibration (only the optimizer's weight decay moves it), while calibration reorders the keep-scores."""
    heads = {}
    for calibration_coef in (0.0, 1.0):
        model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=64, batch_size=32, seed=0,
                          calibration_coef=calibration_coef, vf_coef=0.0)
        model.learn(64 * 3)
        heads[calibration_coef] = {k: v.clone() for k, v in model.policy.retention.state_dict().items()}
    value_keys = [k for k in heads[0.0] if not k.startswith("ranking.")]
    assert all(torch.equal(heads[0.0][k], heads[1.0][k]) for k in value_keys)
    assert all(not heads[0.0][k].any() for k in ("ranking.4.weight", "ranking.4.bias"))  # no calibration: still zero
    assert heads[1.0]["ranking.4.weight"].any()


def test_a_frozen_retriever_stays_put_while_the_critic_learns():
    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=32, batch_size=32, seed=0,
                      calibration_coef=1.0, policy_kwargs={"retriever_lr_scale": 0.0})
    retriever = {k: v.clone() for k, v in model.policy.retriever.state_dict().items()}
    retention = {k: v.clone() for k, v in model.policy.retention.state_dict().items()}
    model.learn(32 * 3)
    assert all(torch.equal(v, model.policy.retriever.state_dict()[k]) for k, v in retriever.items())
    assert not all(torch.equal(v, model.policy.retention.state_dict()[k]) for k, v in retention.items())
    assert [group["lr"] for group in model.policy.optimizer.param_groups] == [0.0, pytest.approx(3e-4)]
    with pytest.raises(ValueError, match="retriever_lr_scale must be >= 0"):
        MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), policy_kwargs={"retriever_lr_scale": -1})
    with pytest.raises(ValueError, match="calibration_coef must be >= 0"):
        MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), calibration_coef=-1)
