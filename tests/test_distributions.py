import itertools
import math

import pytest
import torch

from sb3_memret.policy.distributions import PlackettLuceDistribution


def all_orderings_prob(dist, n, k):
    total = torch.zeros(dist.logits.shape[0])
    for perm in itertools.permutations(range(n), k):
        total += dist.log_prob(torch.tensor([perm] * dist.logits.shape[0])).exp()
    return total


@pytest.mark.parametrize("n,k", [(3, 1), (4, 2), (5, 3), (6, 1)])
def test_probabilities_over_all_orderings_sum_to_one(n, k):
    torch.manual_seed(0)
    scores = torch.randn(4, n)
    mask = torch.ones(4, n, dtype=torch.bool)
    mask[1, 0] = False  # a bank with an empty slot
    dist = PlackettLuceDistribution(k, temperature=0.5).proba_distribution(scores, mask)
    torch.testing.assert_close(all_orderings_prob(dist, n, k), torch.ones(4), atol=1e-5, rtol=0)


def test_log_prob_is_the_product_formula():
    scores, tau = torch.tensor([[1.0, 0.0, -1.0, 2.0]]), 0.5
    dist = PlackettLuceDistribution(2, tau).proba_distribution(scores, torch.ones(1, 4, dtype=torch.bool))
    e = (scores[0] / tau).exp()
    expected = math.log(e[3] / e.sum()) + math.log(e[0] / (e.sum() - e[3]))
    assert dist.log_prob(torch.tensor([[3, 0]])).item() == pytest.approx(expected, rel=1e-5)


def test_masked_slots_are_never_chosen_and_samples_are_distinct():
    torch.manual_seed(1)
    scores = torch.tensor([[5.0, 0.0, 0.0, 9.0, 0.0]]).repeat(2000, 1)
    mask = torch.tensor([[True, True, True, False, True]]).repeat(2000, 1)
    dist = PlackettLuceDistribution(3, 0.5).proba_distribution(scores, mask)
    actions = dist.sample()
    assert not (actions == 3).any()
    assert all(len(set(row.tolist())) == 3 for row in actions)


def test_sampling_matches_probabilities():
    torch.manual_seed(2)
    scores = torch.tensor([[0.3, -0.2, 0.1]])
    dist = PlackettLuceDistribution(1, 0.5).proba_distribution(scores.repeat(20000, 1), torch.ones(20000, 3, dtype=torch.bool))
    freq = torch.bincount(dist.sample()[:, 0], minlength=3).float() / 20000
    torch.testing.assert_close(freq, torch.softmax(scores[0] / 0.5, -1), atol=0.015, rtol=0)


def test_greedy_is_top_k_by_score():
    scores = torch.tensor([[0.1, 0.9, -0.3, 0.5, 0.7]])
    mask = torch.tensor([[True, False, True, True, True]])
    dist = PlackettLuceDistribution(2, 0.5).proba_distribution(scores, mask)
    assert dist.mode().tolist() == [[4, 3]]
    assert dist.get_actions(deterministic=True).tolist() == [[4, 3]]


def test_entropy_uniform_k1_is_log_n_and_k2_matches_enumeration():
    mask = torch.ones(1, 6, dtype=torch.bool)
    uniform = PlackettLuceDistribution(1, 0.5).proba_distribution(torch.zeros(1, 6), mask)
    assert uniform.entropy().item() == pytest.approx(math.log(6), rel=1e-6)
    masked = PlackettLuceDistribution(1, 0.5).proba_distribution(torch.zeros(1, 6), torch.tensor([[1, 1, 1, 0, 0, 0]]))
    assert masked.entropy().item() == pytest.approx(math.log(3), rel=1e-6)
    torch.manual_seed(3)
    scores = torch.randn(1, 4)
    dist = PlackettLuceDistribution(2, 0.7).proba_distribution(scores, torch.ones(1, 4, dtype=torch.bool))
    brute = 0.0
    for perm in itertools.permutations(range(4), 2):
        lp = dist.log_prob(torch.tensor([perm])).item()
        brute -= math.exp(lp) * lp
    assert dist.entropy().item() == pytest.approx(brute, rel=1e-5)



@pytest.mark.parametrize("n,k", [(5, 3), (7, 4), (8, 5)])
def test_entropy_over_sets_equals_the_sum_over_every_ordered_selection_with_empty_slots(n, k):
    torch.manual_seed(n * k)
    scores = 2 * torch.randn(3, n)
    mask = torch.ones(3, n, dtype=torch.bool)
    mask[0, [1, n - 1]] = False  # a bank with two empty slots
    dist = PlackettLuceDistribution(k, 0.5).proba_distribution(scores, mask)
    brute = torch.zeros(3)
    for perm in itertools.permutations(range(n), k):
        lp = dist.log_prob(torch.tensor([perm] * 3))
        brute -= torch.where(lp > -1e8, lp.exp() * lp, torch.zeros_like(lp))
    assert torch.allclose(dist.entropy(), brute, rtol=1e-4)


def test_the_exact_entropy_refuses_a_bank_and_k_too_large_to_sum_over():
    dist = PlackettLuceDistribution(7, 0.5).proba_distribution(torch.zeros(1, 40), torch.ones(1, 40, dtype=torch.bool))
    with pytest.raises(ValueError, match="top-7 over 40 slots sums over 4,598,479 sets"):
        dist.entropy()

def test_entropy_and_log_prob_are_differentiable():
    scores = torch.randn(3, 6, requires_grad=True)
    dist = PlackettLuceDistribution(2, 0.5).proba_distribution(scores, torch.ones(3, 6, dtype=torch.bool))
    (dist.entropy().sum() + dist.log_prob(dist.sample()).sum()).backward()
    assert torch.isfinite(scores.grad).all() and scores.grad.abs().sum() > 0


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="k must be >= 1"):
        PlackettLuceDistribution(0)
    with pytest.raises(ValueError, match="temperature must be > 0"):
        PlackettLuceDistribution(1, 0.0)
    with pytest.raises(ValueError, match="needs at least 2 valid slots"):
        PlackettLuceDistribution(2).proba_distribution(torch.zeros(1, 3), torch.tensor([[1, 0, 0]]))
