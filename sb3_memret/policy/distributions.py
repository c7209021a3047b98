"""A masked Plackett-Luce distribution over ordered top-K selections, for stable-baselines3.

An ordered selection (a_1, ..., a_K) of distinct valid slots has probability
prod_k exp(s_{a_k}/tau) / sum_{j in R_k} exp(s_j/tau), R_k the valid slots not yet chosen.
Sampling uses the Gumbel-top-K trick, which draws exactly from this distribution; the
log-probability is recomputed on the stored ordered selection, at the same temperature. The Gumbel
noise may be given (``sample(noise)``): noise drawn once per episode and reused keeps each decision's
draw exactly Plackett-Luce while an episode's draws agree (``MemoryRetrievalPolicy(exploration="episode")``).
"""

from __future__ import annotations

import functools
import itertools
import math

import torch
from stable_baselines3.common.distributions import Distribution
from torch import nn

NEG_INF = -1e9


def gumbel_noise(shape: tuple[int, ...] | torch.Size, device: torch.device | str = "cpu",
                 generator: torch.Generator | None = None) -> torch.Tensor:
    """Standard Gumbel noise: adding it to logits and taking the top K draws a Plackett-Luce selection."""
    uniform = torch.rand(shape, device=device, generator=generator).clamp_(1e-10, 1 - 1e-10)
    return -torch.log(-torch.log(uniform))


MAX_ENTROPY_SETS = 200_000  # sets the exact entropy sums over: C(20, 6) + ... is 60,460; C(32, 6) alone 906,192


@functools.lru_cache(maxsize=32)
def subset_levels(n: int, k: int) -> tuple[tuple[torch.Tensor, torch.Tensor, torch.Tensor], ...]:
    """For each set size s < k, the sets of s of ``n`` slots: their members (sets, s), each member's set without it
    as an index into the level below (sets, s), and membership masks (sets, n)."""
    count = sum(math.comb(n, s) for s in range(min(k, n + 1)))
    if count > MAX_ENTROPY_SETS:
        raise ValueError(f"the exact Plackett-Luce entropy of a top-{k} over {n} slots sums over {count:,} sets, more "
                         f"than {MAX_ENTROPY_SETS:,}: use a smaller bank or K")
    levels, index = [], {0: 0}
    for size in range(min(k, n + 1)):
        sets = list(itertools.combinations(range(n), size))
        codes = [sum(1 << j for j in members) for members in sets]
        members = torch.tensor(sets, dtype=torch.long).reshape(len(sets), size)
        parents = torch.tensor([[index[code - (1 << j)] for j in members_] for members_, code in zip(sets, codes)],
                               dtype=torch.long).reshape(len(sets), size) if size else members
        taken = torch.zeros(len(sets), n, dtype=torch.bool)
        taken[torch.arange(len(sets)).repeat_interleave(size), members.reshape(-1)] = True
        levels.append((members, parents, taken))
        index = {code: i for i, code in enumerate(codes)}
    return tuple(levels)


class PlackettLuceDistribution(Distribution):
    """Top-``k`` ordered selections among the valid slots of a bank, at temperature ``tau``."""

    def __init__(self, k: int = 1, temperature: float = 0.5):
        super().__init__()
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        if temperature <= 0:
            raise ValueError(f"temperature must be > 0, got {temperature}")
        self.k = k
        self.temperature = temperature
        self.logits: torch.Tensor | None = None  # (B, N) scores / tau, masked slots at NEG_INF
        self.mask: torch.Tensor | None = None

    def proba_distribution_net(self, *args, **kwargs) -> nn.Module:
        raise NotImplementedError("scores come from the retriever network, see MemoryRetrievalPolicy")

    def proba_distribution(self, scores: torch.Tensor, mask: torch.Tensor) -> "PlackettLuceDistribution":
        mask = mask.bool()
        short = mask.sum(-1) < self.k
        if short.any():
            raise ValueError(f"a Plackett-Luce top-{self.k} needs at least {self.k} valid slots; "
                             f"got banks with {mask.sum(-1)[short].tolist()} entries")
        self.mask = mask
        self.logits = torch.where(mask, scores / self.temperature, torch.full_like(scores, NEG_INF))
        return self

    def log_prob(self, actions: torch.Tensor) -> torch.Tensor:
        actions = actions.long().reshape(-1, self.k)
        logits, total = self.logits, torch.zeros(actions.shape[0], device=self.logits.device)
        for step in range(self.k):
            chosen = actions[:, step : step + 1]
            total = total + logits.gather(1, chosen)[:, 0] - torch.logsumexp(logits, dim=-1)
            logits = logits.scatter(1, chosen, NEG_INF)
        return total

    def entropy(self) -> torch.Tensor:
        """Exact entropy by the chain rule over the sets drawn so far: the next draw's law depends on which slots are
        taken, not in what order, so H sums P(S drawn first) H(next given S) over the sets S of fewer than k slots,
        each P(S) summed over S's orders by dynamic programming: sum_{s<k} C(n, s) sets (2,510 for 7 of 12) where the
        orders number n! / (n - s)! (773,665)."""
        batch, n = self.logits.shape
        device = self.logits.device
        levels = [tuple(t.to(device) for t in level) for level in subset_levels(n, self.k)]
        log_p_sets = self.logits.new_zeros(batch, 1)  # log P(S) for the sets of this size: the empty set first
        total = self.logits.new_zeros(batch)
        for size, (members, parents, taken) in enumerate(levels):
            logits = self.logits.unsqueeze(1).masked_fill(taken.unsqueeze(0), NEG_INF)  # (B, sets, n)
            log_p = torch.log_softmax(logits, -1)
            valid = logits > NEG_INF / 2
            step_entropy = -torch.where(valid, log_p.exp() * log_p, torch.zeros_like(log_p)).sum(-1)
            total = total + (log_p_sets.exp() * step_entropy).sum(-1)
            if size + 1 < self.k:  # each larger set T: over its last slot j, P(T \ {j}) p(j | T \ {j})
                nxt_members, nxt_parents, _ = levels[size + 1]
                log_p_next = log_p_sets.unsqueeze(-1) + log_p  # (B, sets, n): S drawn first, then j
                log_p_sets = torch.logsumexp(log_p_next[:, nxt_parents, nxt_members], dim=-1)
        return total

    def sample(self, noise: torch.Tensor | None = None) -> torch.Tensor:
        """An ordered top-K draw: the K largest of logits + Gumbel noise (``noise``: that noise, (B, N); default
        fresh standard Gumbel)."""
        if noise is None:
            noise = gumbel_noise(self.logits.shape, self.logits.device)
        elif noise.shape != self.logits.shape:
            raise ValueError(f"noise of shape {tuple(noise.shape)} for logits of shape {tuple(self.logits.shape)}")
        return torch.topk(self.logits + noise, self.k, dim=-1).indices

    def mode(self) -> torch.Tensor:
        return torch.topk(self.logits, self.k, dim=-1).indices

    def actions_from_params(self, scores: torch.Tensor, mask: torch.Tensor, deterministic: bool = False) -> torch.Tensor:
        self.proba_distribution(scores, mask)
        return self.get_actions(deterministic=deterministic)

    def log_prob_from_params(self, scores: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        actions = self.actions_from_params(scores, mask)
        return actions, self.log_prob(actions)
