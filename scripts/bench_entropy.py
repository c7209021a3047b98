"""Time of the Plackett-Luce entropy (``PlackettLuceDistribution.entropy``: a sum over the sets drawn so far) against
the sum over every ordered prefix it replaced, at the banks and K the zoo configs use.

    python scripts/bench_entropy.py [--batch 32] [--repeats 5] [--max-orders 100000]

For each (slots, K) it prints both times per call (median of ``--repeats``, the set levels' index tables built
before timing), their ratio, and the largest difference between the two values. The sum over orders is skipped
where its prefixes exceed ``--max-orders`` (7 of 12 has 773,665 and takes minutes a call).
"""

from __future__ import annotations

import argparse
import itertools
import math
import statistics
import time

import torch

from sb3_memret.policy.distributions import NEG_INF, PlackettLuceDistribution, subset_levels

CASES = ((6, 1), (6, 3), (8, 3), (10, 5), (12, 7))  # (bank slots, K): the drawer's 6 / 1 up to the 7-colour tasks'


def entropy_over_orders(dist: PlackettLuceDistribution) -> torch.Tensor:
    """The chain rule summed over every ordered prefix of length < k (the baseline)."""
    n = dist.logits.shape[-1]
    total = torch.zeros(dist.logits.shape[0])
    for step in range(dist.k):
        for prefix in itertools.permutations(range(n), step):
            logits, log_p_prefix = dist.logits, torch.zeros_like(total)
            for slot in prefix:
                log_p_prefix = log_p_prefix + logits[:, slot] - torch.logsumexp(logits, -1)
                logits = logits.index_fill(1, torch.tensor([slot]), NEG_INF)
            log_p = torch.log_softmax(logits, -1)
            step_entropy = -torch.where(logits > NEG_INF / 2, log_p.exp() * log_p, torch.zeros_like(log_p)).sum(-1)
            total = total + log_p_prefix.exp() * step_entropy
    return total


def timed(fn, repeats: int) -> tuple[float, torch.Tensor]:
    times, value = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        value = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=32, help="Rows per call (PPO's minibatch).")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--max-orders", type=int, default=100_000)
    args = parser.parse_args()
    torch.manual_seed(0)
    print(f"| slots | K | sets | orders | over sets (ms) | over orders (ms) | ratio | max difference |")
    print("|---|---|---|---|---|---|---|---|")
    for n, k in CASES:
        dist = PlackettLuceDistribution(k, 0.5).proba_distribution(torch.randn(args.batch, n),
                                                                    torch.ones(args.batch, n, dtype=torch.bool))
        subset_levels(n, k)
        dist.entropy()  # a first call warms torch's kernels up
        sets = sum(math.comb(n, s) for s in range(k))
        orders = sum(math.perm(n, s) for s in range(k))
        fast, value = timed(dist.entropy, args.repeats)
        if orders <= args.max_orders:
            slow, reference = timed(lambda: entropy_over_orders(dist), max(1, args.repeats // 2))
            rest = f"{slow * 1e3:.1f} | {slow / fast:.1f}x | {(value - reference).abs().max():.1e}"
        else:
            rest = "not run | | "
        print(f"| {n} | {k} | {sets:,} | {orders:,} | {fast * 1e3:.2f} | {rest} |", flush=True)


if __name__ == "__main__":
    main()
