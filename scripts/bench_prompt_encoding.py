"""What encoding only a batch's own prompts saves in ``finetune``: one training step's prompt path (MiniLM token
features through the policy's attention pooling, forward and backward) for a batch of frames, encoding every
training prompt and indexing the batch's (the old way) against encoding the batch's distinct prompts, taking turns.
SeqOfColors3's progress prompts are the case: 549 prompts of about 70 tokens. ``--hindsight`` adds the pointer's
hindsight term: the old way encoded every prompt with a target again, the new one reuses the batch's vectors.
Prints milliseconds per step and the ratio.

Usage: ``python scripts/bench_prompt_encoding.py [--prompts 549] [--tokens 70] [--batch 256] [--steps 20]
[--hindsight]``
"""

from __future__ import annotations

import argparse
import time

import torch

from sb3_memret.controllers.learned.configuration import LearnedPolicyConfig
from sb3_memret.controllers.learned.modeling import LearnedPolicy


def step_seconds(model: LearnedPolicy, tokens: torch.Tensor, mask: torch.Tensor, tid: torch.Tensor,
                 batch_only: bool, hindsight: bool) -> float:
    """Seconds of one forward and backward pass of the batch's prompt vectors (and of the hindsight term's)."""
    started = time.perf_counter()
    if batch_only:  # finetune's way (DemoTensors.batch): the batch's distinct prompts, once for both terms
        used, which = torch.unique(tid, return_inverse=True)
        encoded = model.encode_prompts(tokens[used], mask[used])
        loss = encoded[which].square().mean() + (encoded.square().mean() if hindsight else 0.0)
    else:  # every prompt, and every prompt again for the hindsight term
        loss = model.encode_prompts(tokens, mask)[tid].square().mean()
        if hindsight:
            loss = loss + model.encode_prompts(tokens, mask).square().mean()
    loss.backward()
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prompts", type=int, default=549)
    parser.add_argument("--tokens", type=int, default=70)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--hindsight", action="store_true", help="add the pointer's hindsight term")
    args = parser.parse_args()
    model = LearnedPolicy(LearnedPolicyConfig(state_names=("x",), state_dim=1))
    generator = torch.Generator().manual_seed(0)
    tokens = torch.randn(args.prompts, args.tokens, model.config.token_dim, generator=generator)
    mask = torch.ones(args.prompts, args.tokens, dtype=torch.bool)
    times: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(args.steps):
        tid = torch.randint(0, args.prompts, (args.batch,), generator=generator)
        for batch_only in (False, True):
            times[batch_only].append(step_seconds(model, tokens, mask, tid, batch_only, args.hindsight))
    every, own = (1000 * sorted(times[k])[len(times[k]) // 2] for k in (False, True))
    print(f"{args.prompts} prompts of {args.tokens} tokens, batch {args.batch}, {torch.get_num_threads()} threads"
          + (", with the hindsight term" if args.hindsight else ""))
    print(f"every prompt, then the batch's: {every:.1f} ms a step (median of {args.steps})")
    print(f"the batch's distinct prompts:   {own:.1f} ms a step ({every / own:.1f}x faster)")


if __name__ == "__main__":
    main()
