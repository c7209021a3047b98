import torch

from sb3_memret.policy.networks import RelevanceMLP, RetentionScorer


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
