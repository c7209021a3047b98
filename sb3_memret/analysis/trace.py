"""The introspection trace: what the retriever thinks of every memory at an episode's first decision.

Each row is a memory in the bank with its retriever score and its first-pick probability
(softmax of score / τ); ``*`` marks the sampled memory, ``C`` the true cube memory, as in the
seed paper's Figure 6. Tracing several models on the same episode seed shows what training
changed (the bank's contents and order depend on the episode, not on the model).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_memret.envs import RECALL_ENV_ID


@dataclass(frozen=True)
class TraceRow:
    slot: int
    text: str
    score: float
    probability: float  # of being the first pick at the policy's temperature
    sampled: bool
    true: bool


@dataclass(frozen=True)
class RetrievalTrace:
    """One model's view of one bank, rows sorted by score, best first."""

    label: str
    instruction: str
    seed: int
    group: str  # the episode's group: the drawer's layer, the cue's colour
    temperature: float
    rows: tuple[TraceRow, ...]

    @property
    def greedy_correct(self) -> bool:
        """Whether the top-scored memory is the true one."""
        return self.rows[0].true

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "greedy_correct": self.greedy_correct}

    def format(self) -> str:
        """A plain-text block like Figure 6 of the seed paper."""
        if not any(row.true for row in self.rows):
            verdict = "a decoy  [the true memory is not in the bank: not yet written, or evicted]"
        else:
            verdict = "the true memory  [CORRECT]" if self.greedy_correct else "a decoy  [WRONG]"
        width = max(len(row.text) for row in self.rows) + 4
        lines = [f"{self.label}  retriever top-1 = {verdict}",
                 f"  {'':{width}}{'score':>8}{'p(first)':>10}"]
        for row in self.rows:
            marks = ("*" if row.sampled else " ") + ("C" if row.true else " ")
            lines.append(f"{marks} {row.text:{width - 1}}{row.score:+8.3f}{row.probability:10.1%}")
        return "\n".join(lines)


@torch.no_grad()
def trace_first_retrieval(model: BaseAlgorithm, env: gym.Env, seed: int, label: str, sample_seed: int = 0) -> RetrievalTrace:
    """Reset ``env`` with ``seed`` and score its bank with ``model``; the sampled pick is a
    Plackett-Luce draw at the policy's temperature from ``sample_seed`` (global RNG untouched)."""
    obs, info = env.reset(seed=seed)
    policy = model.policy
    # the models traced together may differ in whether their critic reads the potential
    tensors, _ = policy.obs_to_tensor({k: obs[k] for k in policy.observation_space.spaces})
    features = policy.extract_features(tensors)
    mask = (tensors["mask"] > 0.5)[0].cpu().numpy()
    scores = policy.scores(features)[0].cpu().numpy().astype(np.float64)  # float64: tiny probabilities stay > 0
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(sample_seed)
        sampled = set(policy.get_distribution(tensors).get_actions(deterministic=False)[0].tolist())
    valid = np.flatnonzero(mask)
    logits = scores[valid] / policy.temperature
    probs = np.exp(logits - logits.max())
    probs /= probs.sum()
    texts = info["memory_texts"]
    rows = [TraceRow(int(slot), texts[slot], float(scores[slot]), float(p), int(slot) in sampled,
                     int(slot) in info["true_slots"]) for slot, p in zip(valid, probs)]
    rows.sort(key=lambda row: -row.score)
    instruction = env.unwrapped.instruction()
    return RetrievalTrace(label, instruction, seed, str(info["group"]), float(policy.temperature), tuple(rows))


def trace_models(models: list[tuple[str, BaseAlgorithm]], env_kwargs: dict[str, Any], seed: int,
                 sample_seed: int = 0) -> list[RetrievalTrace]:
    """Trace each (label, model) on the same episode, in one env."""
    env = gym.make(RECALL_ENV_ID, **env_kwargs)
    try:
        return [trace_first_retrieval(model, env, seed, label, sample_seed) for label, model in models]
    finally:
        env.close()


def model_label(model: BaseAlgorithm, path: Path) -> str:
    """``<file> (round N)``: N = PPO updates the model has had."""
    return f"{Path(path).name} (round {model._n_updates // model.n_epochs})"


__all__ = ["RetrievalTrace", "TraceRow", "model_label", "trace_first_retrieval", "trace_models"]
