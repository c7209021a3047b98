"""MemRetPPO: PPO with per-round advantage normalisation and retention weights pushed to the envs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_memret.policy.policy import MemoryRetrievalPolicy

# The paper's PPO settings (appendix A).
PAPER_HYPERPARAMS: dict[str, Any] = dict(gamma=0.97, clip_range=0.2, n_epochs=4, learning_rate=3e-4,
                                         ent_coef=0.001, vf_coef=0.5)


class MemRetPPO(PPO):
    """PPO for the memory learner.

    * Advantages are normalised once over the whole round (the rollout), not per minibatch.
    * At the start of every rollout the retention network's weights are pushed to every env
      (``set_retention_weights``), so eviction during collection uses the current critic.
    """

    def __init__(self, policy: type | str = MemoryRetrievalPolicy, env: Any = None, **kwargs: Any):
        for key, value in PAPER_HYPERPARAMS.items():
            kwargs.setdefault(key, value)
        kwargs["normalize_advantage"] = False  # done per round in train()
        super().__init__(policy, env, **kwargs)

    def collect_rollouts(self, env: VecEnv, callback: BaseCallback, rollout_buffer: RolloutBuffer,
                         n_rollout_steps: int) -> bool:
        env.env_method("set_retention_weights", self.policy.retention_state_dict(), age_unit=self.policy.age_unit)
        return super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)

    def train(self) -> None:
        adv = self.rollout_buffer.advantages
        self.rollout_buffer.advantages = (adv - adv.mean()) / (adv.std() + 1e-8)
        self.logger.record("train/raw_advantage_std", float(adv.std()))
        super().train()


def load_model(path: str | Path, device: str = "cpu", **kwargs: Any) -> MemRetPPO:
    """``MemRetPPO.load`` that refuses, in one line, a file that is not a saved memory learner."""
    try:
        model = MemRetPPO.load(path, device=device, **kwargs)
    except Exception as err:  # a missing, truncated or foreign file surfaces as many error types
        reason = str(err).splitlines()[0].removeprefix("Error: ") if str(err) else type(err).__name__
        raise ValueError(f"{str(path)!r} is not a model saved by sb3-memret (a .zip written by sb3-memret train, "
                         f"e.g. final_model.zip or checkpoints/memret_<steps>_steps.zip): {reason}") from None
    if not isinstance(model.policy, MemoryRetrievalPolicy):
        raise ValueError(f"{str(path)!r} holds a {type(model.policy).__name__}, not sb3-memret's "
                         "MemoryRetrievalPolicy")
    return model
