import torch

from sb3_memret.policy.networks import RelevanceMLP, RetentionScorer, SetRetriever


def test_retriever_shapes_and_layer_sizes():
    net = RelevanceMLP()
    scores = net(torch.randn(5, 384), torch.randn(5, 6, 384))
    assert scores.shape == (5, 6)
    linears = [m for m in net.modules() if isinstance(m, torch.nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(1536, 128), (128, 128), (128, 1)]


def test_retriever_scores_each_memory_independently_of_slot_order():
    torch.manual_seed(0)
    net, g, m = RelevanceMLP(), torch.randn(2, 384), torch.randn(2, 6, 384)
    perm = torch.randperm(6)
    torch.testing.assert_close(net(g, m)[:, perm], net(g, m[:, perm]))


def test_retention_shapes_sizes_and_masked_value():
    torch.manual_seed(0)
    net = RetentionScorer()
    linears = [m for m in net.net.modules() if isinstance(m, torch.nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(418, 128), (128, 128), (128, 1)]
    mem, types = torch.randn(3, 6, 384), torch.randint(0, 6, (3, 6))
    age, usage = torch.rand(3, 6) * 100, torch.rand(3, 6) * 5
    scores = net(mem, types, age, usage)
    assert scores.shape == (3, 6)
    mask = torch.tensor([[1, 1, 1, 1, 1, 1], [1, 1, 0, 0, 0, 0], [1, 0, 0, 0, 0, 0]], dtype=torch.bool)
    value = net.value(mem, types, age, usage, mask)
    torch.testing.assert_close(value, torch.stack([scores[0].mean(), scores[1, :2].mean(), scores[2, 0]]))


def test_retention_ranking_head_reorders_eviction_without_moving_the_value():
    """Keep-scores are the value head plus the ranking head (zero at the start); the value reads the value
    head only, and the calibration scores let gradient reach the ranking head only."""
    torch.manual_seed(0)
    net = RetentionScorer()
    mem, types, age, usage = torch.randn(2, 6, 384), torch.randint(0, 6, (2, 6)), torch.rand(2, 6), torch.rand(2, 6)
    mask = torch.ones(2, 6, dtype=torch.bool)
    value_before = net.value(mem, types, age, usage, mask).detach()
    torch.nn.init.normal_(net.ranking[-1].weight)
    torch.testing.assert_close(net.value(mem, types, age, usage, mask), value_before)
    assert not torch.allclose(net(mem, types, age, usage).mean(-1), value_before)
    net.calibration_scores(mem, types, age, usage).sum().backward()
    assert all(p.grad is None for p in [*net.net.parameters(), *net.type_embedding.parameters()])
    assert all(p.grad is not None for p in net.ranking.parameters())


def test_retention_ranking_head_draws_nothing_from_the_global_stream_and_old_models_load():
    """Runs of one seed start as they did before the ranking head existed, and a state saved without it
    loads with the head at its zero start (keep-scores exactly the value head's)."""
    torch.manual_seed(2)
    net, after = RetentionScorer(), torch.rand(3)
    torch.manual_seed(2)
    torch.nn.Embedding(6, 32), torch.nn.Linear(418, 128), torch.nn.Linear(128, 128), torch.nn.Linear(128, 1)
    torch.testing.assert_close(after, torch.rand(3))
    saved = {k: v for k, v in net.state_dict().items() if not k.startswith("ranking.")}
    torch.manual_seed(5)
    loaded = RetentionScorer()
    loaded.load_state_dict(saved)
    mem, types, age, usage = torch.randn(1, 6, 384), torch.randint(0, 6, (1, 6)), torch.rand(1, 6), torch.rand(1, 6)
    torch.testing.assert_close(loaded(mem, types, age, usage), net(mem, types, age, usage))


def test_set_retriever_is_permutation_equivariant_over_any_bank_size():
    torch.manual_seed(0)
    retriever = SetRetriever()
    g, memories = torch.randn(2, 384), torch.randn(2, 6, 384)
    mask = torch.ones(2, 6, dtype=torch.bool)
    scores = retriever(g, memories, mask)
    order = torch.tensor([3, 0, 5, 1, 4, 2])
    torch.testing.assert_close(retriever(g, memories[:, order], mask[:, order]), scores[:, order])
    assert retriever(g, torch.randn(2, 11, 384), torch.ones(2, 11, dtype=torch.bool)).shape == (2, 11)


def test_set_retriever_scores_depend_on_the_other_valid_memories_only():
    """Unlike the per-memory MLP, a memory's score changes with its rivals; empty slots change nothing."""
    torch.manual_seed(1)
    retriever = SetRetriever()
    torch.nn.init.normal_(retriever.context.weight)  # a trained context head (it starts at zero)
    g, memories = torch.randn(1, 384), torch.randn(1, 6, 384)
    mask = torch.tensor([[True, True, True, True, False, False]])
    scores = retriever(g, memories, mask)
    garbage = memories.clone()
    garbage[0, 4:] = 50.0
    torch.testing.assert_close(retriever(g, garbage, mask)[0, :4], scores[0, :4])
    rival = memories.clone()
    rival[0, 3] = torch.randn(384)
    assert not torch.allclose(retriever(g, rival, mask)[0, :3], scores[0, :3])
    empty = retriever(g, memories, torch.zeros(1, 6, dtype=torch.bool))
    assert torch.isfinite(empty).all()


def test_set_retriever_starts_as_the_per_memory_mlp_of_the_same_seed():
    """Its context head starts at zero and its attention draws from its own stream: built after the same
    seed, it scores as the MLP and leaves the global random stream where the MLP leaves it."""
    torch.manual_seed(2)
    mlp, after_mlp = RelevanceMLP(), torch.rand(3)
    torch.manual_seed(2)
    retriever, after_set = SetRetriever(), torch.rand(3)
    torch.testing.assert_close(after_set, after_mlp)
    g, memories = torch.randn(3, 384), torch.randn(3, 6, 384)
    mask = torch.tensor([[True] * 6, [True] * 3 + [False] * 3, [True] + [False] * 5])
    torch.testing.assert_close(retriever(g, memories, mask), mlp(g, memories))
    torch.manual_seed(3)
    assert not torch.equal(SetRetriever().attention.layers[0].linear1.weight, retriever.attention.layers[0].linear1.weight)
