"""Retrieval statistics of the training rollouts themselves, logged once per round."""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback


class RolloutRetrievalCallback(BaseCallback):
    """Logs, for the decisions PPO collected this round, how often the sampled selection held
    every memory the controller needs (``rollout/sampled_fraction``), plus success, true-memory evictions and the
    mean shaped reward of the episodes that ended in the round, and how many physics workers have
    died and been restarted so far (``RecallVecEnv.physics_restarts``).

    It also logs what the round teaches the retriever, from the advantages PPO is about to train on:
    ``rollout/advantage_gap`` is the mean advantage of decisions that retrieved every needed memory minus
    that of decisions that did not, in units of the round's advantage std, and ``rollout/advantage_gap_t``
    its Welch t statistic (near 0: the round's update is noise for retrieval). ``rollout/score_margin``
    is the mean over those decisions of the least true memory's score minus the best other memory's,
    divided by the temperature (the logit gap the Plackett-Luce draw sees; > 0 means greedy is right),
    and ``rollout/greedy_accuracy`` the share of them with a positive margin.
    """

    def __init__(self, verbose: int = 0):
        super().__init__(verbose)
        self._reset_counts()

    def _reset_counts(self) -> None:
        self.decisions = self.hits = self.steps = 0
        self.reward = 0.0
        self.successes: list[bool] = []
        self.evicted: list[bool] = []
        self.retrieved: list[list[bool]] = []  # per collected step, per env
        self.true_slots: list[list[list[int]]] = []  # empty where some needed memory was not in the bank

    def _on_rollout_start(self) -> None:
        self._reset_counts()

    def _on_step(self) -> bool:
        retrieved, true_slots = [], []
        for info, reward, done in zip(self.locals["infos"], self.locals["rewards"], self.locals["dones"]):
            self.steps += 1
            self.reward += float(reward)
            true = list(info.get("decision_true_slots") or [])
            retrieved.append(bool(info.get("retrieved_true", False)))
            true_slots.append(true)
            if true:  # every needed memory was in the bank
                self.decisions += 1
                self.hits += bool(info["retrieved_true"])
            if info.get("task_done", done):  # a household's learning episode spans several tasks
                self.successes.append(bool(info["success"]))
                self.evicted.append(bool(info["true_evicted"]))
        self.retrieved.append(retrieved)
        self.true_slots.append(true_slots)
        return True

    def _on_rollout_end(self) -> None:
        record = self.logger.record
        record("rollout/sampled_fraction", self.hits / max(self.decisions, 1))
        record("rollout/mean_reward", self.reward / max(self.steps, 1))
        record("rollout/episodes", len(self.successes))
        restarts = getattr(self.training_env.unwrapped, "physics_restarts", None)
        if restarts is not None:
            record("rollout/physics_restarts", restarts)
        if self.successes:
            record("rollout/success", float(np.mean(self.successes)))
            record("rollout/true_evicted_rate", float(np.mean(self.evicted)))
        buffer = getattr(self.model, "rollout_buffer", None)
        if buffer is not None and buffer.full and len(self.true_slots) == buffer.buffer_size:
            for key, value in {**self._advantage_gap(buffer.advantages), **self._score_margins(buffer)}.items():
                record(f"rollout/{key}", value)

    def _advantage_gap(self, advantages: np.ndarray) -> dict[str, float]:
        """How far the round's advantages separate decisions that retrieved every needed memory from the rest."""
        counted = np.array([[bool(true) for true in per_env] for per_env in self.true_slots])
        retrieved = np.array(self.retrieved)
        hit, miss = advantages[counted & retrieved], advantages[counted & ~retrieved]
        if len(hit) < 2 or len(miss) < 2:
            return {}
        scale = float(advantages.std()) + 1e-8
        gap = float(hit.mean() - miss.mean())
        stderr = float(np.sqrt(hit.var(ddof=1) / len(hit) + miss.var(ddof=1) / len(miss))) + 1e-12
        return {"advantage_gap": gap / scale, "advantage_gap_t": gap / stderr}

    @torch.no_grad()
    def _score_margins(self, buffer) -> dict[str, float]:
        """The policy's logit gap between the needed memories and the best other one, on the round's states."""
        policy = self.model.policy
        if not hasattr(policy, "scores"):
            return {}
        rows = [(step, env) for step, per_env in enumerate(self.true_slots) for env, true in enumerate(per_env) if true]
        if not rows:
            return {}
        steps, envs = map(np.array, zip(*rows))
        obs = {key: torch.as_tensor(value[steps, envs], device=policy.device) for key, value in buffer.observations.items()}
        scores = policy.scores(obs).cpu().numpy() / policy.temperature
        valid = obs["mask"].cpu().numpy() > 0.5
        margins = []
        for row, (step, env) in enumerate(rows):
            true = np.zeros(scores.shape[1], dtype=bool)
            true[self.true_slots[step][env]] = True
            others = valid[row] & ~true
            if others.any():
                margins.append(scores[row, true].min() - scores[row, others].max())
        if not margins:
            return {}
        margins = np.array(margins)
        return {"score_margin": float(margins.mean()), "greedy_accuracy": float((margins > 0).mean())}
