"""What each memory was worth to the retrievals that followed: the label-free target that calibrates the
retention critic's keep-scores for eviction.

The value loss fits only the mean keep-score of a bank to the return, so it says nothing about which
memory to evict: any keep-scores with the right mean fit it. Eviction needs the ranking. A memory's credit
at decision t is the positive advantage of every later decision of the same episode that retrieved it,
discounted by (gamma * lambda) per decision, as GAE discounts TD errors:

    C_t(m) = 1[m retrieved at t] * max(A_t, 0) + gamma * lambda * C_{t+1}(m)

No label says which memory is right: only what the retriever chose and how that turned out. The
calibration loss is a cross-entropy between the keep-scores' softmax over a bank's valid slots and the
credits normalised over them. It is blind to a shift of every keep-score and trains only the critic's
ranking head (``RetentionScorer``): the ranking that eviction reads moves, the value that PPO's
advantages read stays the value loss's. Memories are told apart by their embeddings (a
memory keeps its embedding while it stays in the bank, whichever slot it sits in).
"""

from __future__ import annotations

import numpy as np
import torch


def retrieval_credit(memories: np.ndarray, mask: np.ndarray, actions: np.ndarray, advantages: np.ndarray,
                     episode_starts: np.ndarray, discount: float) -> np.ndarray:
    """Per-slot credit (n_steps, n_envs, N) of a round.

    ``memories`` (n_steps, n_envs, N, D), ``mask`` (n_steps, n_envs, N) the valid slots, ``actions``
    (n_steps, n_envs, K) the retrieved slots, ``advantages`` (n_steps, n_envs), ``episode_starts``
    (n_steps, n_envs) 1 where an episode began, ``discount`` gamma * lambda. A memory's credit stops at its
    episode's end, and at the round's (what comes after is not known yet).
    """
    n_steps, n_envs, slots = mask.shape
    actions = actions.reshape(n_steps, n_envs, -1).astype(np.int64)
    credit = np.zeros((n_steps, n_envs, slots), dtype=np.float32)
    for env in range(n_envs):
        carried: dict[bytes, float] = {}  # credit of each memory (by its embedding) from the decisions after t
        for t in range(n_steps - 1, -1, -1):
            if t + 1 < n_steps and episode_starts[t + 1, env]:
                carried = {}
            carried = {key: discount * value for key, value in carried.items()}
            keys = [memories[t, env, i].tobytes() for i in range(slots)]
            gain = max(float(advantages[t, env]), 0.0)
            for slot in set(actions[t, env].tolist()):
                if mask[t, env, slot] > 0.5:
                    carried[keys[slot]] = carried.get(keys[slot], 0.0) + gain
            credit[t, env] = [carried.get(key, 0.0) if mask[t, env, i] > 0.5 else 0.0 for i, key in enumerate(keys)]
    return credit


def calibration_loss(keep_scores: torch.Tensor, credit: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Cross-entropy between softmax(keep-scores) over each bank's valid slots and its normalised credit,
    averaged over the banks with any credit (0 when none has)."""
    mask = mask.bool()
    total = (credit * mask).sum(-1)
    has = total > 0
    if not has.any():
        return keep_scores.sum() * 0.0
    target = (credit * mask)[has] / total[has, None]
    log_p = torch.log_softmax(keep_scores[has].masked_fill(~mask[has], -1e9), dim=-1)
    return -(target * log_p.masked_fill(~mask[has], 0.0)).sum(-1).mean()


__all__ = ["calibration_loss", "retrieval_credit"]
