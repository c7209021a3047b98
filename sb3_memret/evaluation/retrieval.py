"""Held-out evaluation of a memory policy: retrieval quality and task success in one pass.

Retrieval is scored at every decision where every memory the controller needs (the drawer's
one, a sequence's several) is in the bank: greedy accuracy (the acted top-K contains them all),
the sampled fraction (how often a Plackett-Luce draw at the training temperature would contain
them all, estimated from ``samples`` draws per state), and the policy entropy. Task success is
reported per group (the drawer's layer, a cue's word).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from sb3_memret.policy.distributions import gumbel_noise


# what a household's long-term store held before each task (``EpisodeMemory.info``)
HOUSEHOLD_FLAGS = ("needed_fact_gone", "target_fact_kept", "stale_fact_kept")


@dataclass
class RetrievalReport:
    """What one held-out evaluation measured; ``as_metrics`` flattens it for a logger."""

    episodes: int
    decisions: int  # decisions with every needed memory in the bank
    greedy_accuracy: float
    sampled_fraction: float
    entropy: float
    success: dict[str, float] = field(default_factory=dict)  # "overall" and one key per group (the drawer's layer, the cue's colour)
    episodes_per_group: dict[str, int] = field(default_factory=dict)
    mean_return: float = 0.0  # shaped return per episode
    mean_reward: float = 0.0  # shaped reward per decision
    true_evicted_rate: float = 0.0
    # households, before each task's glimpse: the target was seen since the last move, yet its fact is not kept;
    # the store keeps the target's true fact; it keeps a stale one (another drawer)
    needed_fact_gone_rate: float | None = None
    target_fact_kept_rate: float | None = None
    stale_fact_kept_rate: float | None = None
    deterministic: bool = True

    def as_metrics(self) -> dict[str, float]:
        metrics = {
            "greedy_accuracy" if self.deterministic else "acted_accuracy": self.greedy_accuracy,
            "sampled_fraction": self.sampled_fraction,
            "entropy": self.entropy,
            "success": self.success["overall"],
            "mean_return": self.mean_return,
            "mean_reward": self.mean_reward,
            "true_evicted_rate": self.true_evicted_rate,
            "episodes": float(self.episodes),
        }
        metrics.update({f"success_group_{k}": v for k, v in self.success.items() if k != "overall"})
        metrics.update({f"{flag}_rate": getattr(self, f"{flag}_rate") for flag in HOUSEHOLD_FLAGS
                        if getattr(self, f"{flag}_rate") is not None})
        return metrics

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "RetrievalReport":
        """A report as ``to_dict`` wrote it; runs saved before success was grouped by task name the
        groups ``episodes_per_layer``."""
        data = dict(data)
        if "episodes_per_layer" in data:
            data["episodes_per_group"] = data.pop("episodes_per_layer")
        return cls(**data)


@torch.no_grad()
def evaluate_retrieval(
    model: BaseAlgorithm,
    venv: VecEnv,
    n_episodes: int = 50,
    seed: int | None = None,
    deterministic: bool = True,
    samples: int = 32,
    on_episode: Callable[[dict[str, Any]], None] | None = None,
    task_seeds: Sequence[int] | None = None,
    held_out: str = "development",
) -> RetrievalReport:
    """Run ``n_episodes`` (split over the envs of ``venv`` as SB3's ``evaluate_policy`` does) and
    score retrieval and success. ``seed`` reseeds the envs first so the episodes are reproducible.
    The task envs start at ``task_seeds``, each seed played once, in contiguous blocks per env; by default at
    each env's task's ``held_out`` seeds where it has them (``RecallVecEnv.held_out_seed_blocks``): "development"
    (MIKASA's 5000 + i: what training and every choice play), or "evaluation", its protocol's test set (MIKASA's
    4242424242 + i), for the final figure only, asked for by name.
    The model's retention critic is pushed to the envs first, so it evicts as it did in training.
    Its random draws (the sampled-fraction estimate, stochastic actions) come from a generator of its own,
    seeded by ``seed``: an evaluation leaves torch's global random state, and so training, as it found it."""
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    policy = model.policy
    if hasattr(policy, "retention_state_dict"):
        venv.env_method("set_retention_weights", policy.retention_state_dict(), age_unit=policy.age_unit)
    was_training = policy.training
    policy.set_training_mode(False)
    n = venv.num_envs
    targets = np.array([(n_episodes + i) // n for i in range(n)])
    counts = np.zeros(n, dtype=int)
    returns, evicted, lengths = np.zeros(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=int)
    hits = sampled = entropy = decisions = 0.0
    rewards_total, steps_total = 0.0, 0
    episodes: list[dict[str, Any]] = []
    blocks = None
    if task_seeds is not None:
        if len(task_seeds) < n_episodes:
            raise ValueError(f"{n_episodes} episodes need as many task seeds, got {len(task_seeds)}")
        starts = np.concatenate([[0], np.cumsum(targets)])
        blocks = [list(task_seeds[starts[i]:starts[i + 1]]) for i in range(n)]
    elif hasattr(venv, "held_out_seed_blocks"):
        blocks = venv.held_out_seed_blocks(targets, held_out)
    if blocks is not None:
        venv.env_method("set_task_seeds", blocks)
    if seed is not None:
        venv.seed(seed)
    obs = venv.reset()
    generator = torch.Generator(device=policy.device).manual_seed(seed or 0)
    try:
        while (counts < targets).any():
            obs_t, _ = policy.obs_to_tensor(obs)
            dist = policy.get_distribution(obs_t)
            shape = dist.logits.shape
            actions = dist.mode() if deterministic else dist.sample(gumbel_noise(shape, policy.device, generator))
            draws = torch.stack([dist.sample(gumbel_noise(shape, policy.device, generator)) for _ in range(samples)],
                                dim=1)  # (B, S, K)
            ent = dist.entropy()
            obs, rewards, dones, infos = venv.step(actions.cpu().numpy())
            for i, info in enumerate(infos):
                if counts[i] >= targets[i]:
                    continue
                returns[i] += rewards[i]
                lengths[i] += 1
                rewards_total, steps_total = rewards_total + float(rewards[i]), steps_total + 1
                evicted[i] |= bool(info["true_evicted"])
                true = list(info["decision_true_slots"])
                if true:  # every needed memory was in the bank
                    decisions += 1
                    hits += bool(info["retrieved_true"])
                    held = torch.stack([(draws[i] == slot).any(-1) for slot in true]).all(0)  # (S,) all retrieved
                    sampled += float(held.float().mean())
                    entropy += float(ent[i])
                if info.get("task_done", dones[i]):  # a household's learning episode spans several tasks
                    episode = dict(group=str(info["group"]), success=bool(info["success"]),
                                   shaped_return=float(returns[i]), true_evicted=bool(evicted[i]),
                                   decisions=int(lengths[i]), target=info.get("target", "cube"),
                                   task_seed=info.get("task_seed"))
                    episode.update({flag: bool(info[flag]) for flag in HOUSEHOLD_FLAGS if flag in info})
                    episodes.append(episode)
                    if on_episode is not None:
                        on_episode(episode)
                    counts[i] += 1
                    returns[i], evicted[i], lengths[i] = 0.0, False, 0
    finally:
        policy.set_training_mode(was_training)
        if blocks is not None:
            venv.env_method("set_task_seeds", [[] for _ in range(n)])
    return _report(episodes, decisions, hits, sampled, entropy, rewards_total / max(steps_total, 1), deterministic)


def _report(episodes: list[dict[str, Any]], decisions: float, hits: float, sampled: float, entropy: float,
            mean_reward: float, deterministic: bool) -> RetrievalReport:
    success = {"overall": float(np.mean([e["success"] for e in episodes]))}
    per_group = {}
    for key in sorted({e["group"] for e in episodes}):
        group = [e["success"] for e in episodes if e["group"] == key]
        per_group[key] = len(group)
        success[key] = float(np.mean(group))
    safe = max(decisions, 1.0)
    return RetrievalReport(
        episodes=len(episodes), decisions=int(decisions), greedy_accuracy=hits / safe, sampled_fraction=sampled / safe,
        entropy=entropy / safe, success=success, episodes_per_group=per_group,
        mean_return=float(np.mean([e["shaped_return"] for e in episodes])), mean_reward=mean_reward,
        true_evicted_rate=float(np.mean([e["true_evicted"] for e in episodes])), deterministic=deterministic,
        **{f"{flag}_rate": float(np.mean([e[flag] for e in episodes])) if all(flag in e for e in episodes) else None
           for flag in HOUSEHOLD_FLAGS},
    )


__all__ = ["HOUSEHOLD_FLAGS", "RetrievalReport", "evaluate_retrieval"]
