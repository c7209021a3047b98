"""Retrieval statistics of the training rollouts themselves, logged once per round."""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback


class RolloutRetrievalCallback(BaseCallback):
    """Logs, for the decisions PPO collected this round, how often the sampled selection held
    every memory the controller needs (``rollout/sampled_fraction``), plus success, true-memory evictions and the
    mean shaped reward of the episodes that ended in the round, and how many physics workers have
    died and been restarted so far (``RecallVecEnv.physics_restarts``)."""

    def __init__(self, verbose: int = 0):
        super().__init__(verbose)
        self._reset_counts()

    def _reset_counts(self) -> None:
        self.decisions = self.hits = self.steps = 0
        self.reward = 0.0
        self.successes: list[bool] = []
        self.evicted: list[bool] = []

    def _on_rollout_start(self) -> None:
        self._reset_counts()

    def _on_step(self) -> bool:
        for info, reward, done in zip(self.locals["infos"], self.locals["rewards"], self.locals["dones"]):
            self.steps += 1
            self.reward += float(reward)
            if info.get("decision_true_slots"):  # every needed memory was in the bank
                self.decisions += 1
                self.hits += bool(info["retrieved_true"])
            if info.get("task_done", done):  # a household's learning episode spans several tasks
                self.successes.append(bool(info["success"]))
                self.evicted.append(bool(info["true_evicted"]))
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
