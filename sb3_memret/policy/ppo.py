"""MemRetPPO: PPO with per-round advantage normalisation and retention weights pushed to the envs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_memret.policy.credit import calibration_loss, retrieval_credit
from sb3_memret.policy.policy import MemoryRetrievalPolicy

# The paper's PPO settings (appendix A).
PAPER_HYPERPARAMS: dict[str, Any] = dict(gamma=0.97, clip_range=0.2, n_epochs=4, learning_rate=3e-4,
                                         ent_coef=0.001, vf_coef=0.5)


class MemRetPPO(PPO):
    """PPO for the memory learner.

    * Advantages are normalised once over the whole round (the rollout), not per minibatch, and divided by no
      less than ``advantage_std_floor`` times the widest spread a round of this run has had: once the learner is
      right nearly everywhere a round's advantages are only the critic's noise, and scaling that noise up to unit
      spread pushed a converged retriever off its answer (in the two-task test, greedy 100% fell to 28-76% for a
      round in 5 of 12 seeds; with the floor at 0.25, in 0 of 24). The floor is relative because the reward's
      scale differs by task (a round's spread is 0.05 on RememberColor3, 2-3 on InterceptSlow).
    * At the start of every rollout the retention network's weights are pushed to every env
      (``set_retention_weights``), so eviction during collection uses the current critic.
    * With the policy's ``exploration="episode"`` each env keeps its Plackett-Luce noise for a whole
      episode, across rounds, and draws a new one when its episode ends.
    * ``calibration_coef > 0``: after each PPO update, ``n_epochs`` passes of the retention critic's ranking
      head alone on the calibration loss (``sb3_memret.policy.credit``): keep-scores ranked by what each
      memory was worth to the retrievals that followed, which is what eviction reads; the value head, and so
      the advantages, stay the value loss's alone.
    * The policy's ``retriever_lr_scale`` (its optimizer's parameter groups) survives SB3's learning-rate
      schedule: a warm-started retriever can learn slower than the critic, or not at all (0).
    """

    def __init__(self, policy: type | str = MemoryRetrievalPolicy, env: Any = None, calibration_coef: float = 0.0,
                 advantage_std_floor: float = 0.25, **kwargs: Any):
        if calibration_coef < 0:
            raise ValueError(f"calibration_coef must be >= 0, got {calibration_coef}")
        if not 0 <= advantage_std_floor <= 1:
            raise ValueError(f"advantage_std_floor must be in [0, 1] (a fraction of the widest round spread), "
                             f"got {advantage_std_floor}")
        self.calibration_coef = calibration_coef
        self.advantage_std_floor = advantage_std_floor
        self.widest_advantage_std = 0.0  # the widest spread of a round's raw advantages so far (saved, so resumed)
        for key, value in PAPER_HYPERPARAMS.items():
            kwargs.setdefault(key, value)
        kwargs["normalize_advantage"] = False  # done per round in train()
        self._episode_noise = None  # exploration="episode": each env's Plackett-Luce noise, kept between rounds
        super().__init__(policy, env, **kwargs)

    def collect_rollouts(self, env: VecEnv, callback: BaseCallback, rollout_buffer: RolloutBuffer,
                         n_rollout_steps: int) -> bool:
        env.env_method("set_retention_weights", self.policy.retention_state_dict(), age_unit=self.policy.age_unit)
        if getattr(self.policy, "exploration", "decision") != "episode":
            return super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)
        self.policy.episode_noise = self._episode_noise  # the noise of the episodes under way
        if self._episode_noise is None or self._episode_noise.shape[0] != env.num_envs:
            self.policy.redraw_noise(env.num_envs)
        try:
            return super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)
        finally:  # outside collection (predict, evaluation) every draw is fresh
            self._episode_noise, self.policy.episode_noise = self.policy.episode_noise, None

    def _update_info_buffer(self, infos: list[dict[str, Any]], dones: np.ndarray | None = None) -> None:
        """SB3 calls this after every collection step: envs whose episode ended draw new episode noise."""
        super()._update_info_buffer(infos, dones)
        if self.policy.episode_noise is not None and dones is not None and np.any(dones):
            self.policy.redraw_noise(len(dones), np.flatnonzero(dones))

    def _setup_learn(self, total_timesteps: int, callback: Any = None, reset_num_timesteps: bool = True,
                     tb_log_name: str = "run", progress_bar: bool = False):
        if reset_num_timesteps or self._last_obs is None:  # SB3 resets the envs: every episode starts anew
            self._episode_noise = None
        return super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_episode_noise"]

    def _update_learning_rate(self, optimizers: Any) -> None:
        """SB3 sets one learning rate on every parameter group; each group keeps its ``lr_scale`` of it."""
        super()._update_learning_rate(optimizers)
        for optimizer in optimizers if isinstance(optimizers, list) else [optimizers]:
            for group in optimizer.param_groups:
                group["lr"] *= group.get("lr_scale", 1.0)

    def train(self) -> None:
        adv = self.rollout_buffer.advantages
        spread = float(adv.std())
        self.widest_advantage_std = max(self.widest_advantage_std, spread)
        scale = max(spread, self.advantage_std_floor * self.widest_advantage_std, 1e-8)
        self.rollout_buffer.advantages = (adv - adv.mean()) / scale
        self.logger.record("train/raw_advantage_std", spread)
        self.logger.record("train/advantage_scale", scale)
        calibration = self._calibration_data() if self.calibration_coef > 0 else None  # before SB3 flattens the buffer
        super().train()
        if calibration is not None:
            self._calibrate_retention(*calibration)

    def _calibration_data(self) -> tuple[dict[str, torch.Tensor], np.ndarray]:
        """The round's bank observations, one row per decision, and each memory's retrieval credit."""
        buffer = self.rollout_buffer
        obs = buffer.observations
        credit = retrieval_credit(obs["memories"], obs["mask"], buffer.actions, buffer.advantages,
                                  buffer.episode_starts, self.gamma * self.gae_lambda)
        flat = {key: torch.as_tensor(obs[key].reshape(-1, *obs[key].shape[2:]), device=self.device)
                for key in ("memories", "mask", "type_ids", "age", "usage", "store_ids") if key in obs}
        return flat, credit

    def _calibrate_retention(self, flat: dict[str, torch.Tensor], credit: np.ndarray) -> None:
        """Fit the keep-scores' ranking to each memory's retrieval credit (``sb3_memret.policy.credit``)."""
        credit_t = torch.as_tensor(credit.reshape(-1, credit.shape[-1]), device=self.device)
        retention, optimizer = self.policy.retention, self.policy.optimizer
        losses = []
        for _ in range(self.n_epochs):
            for batch in torch.randperm(len(credit_t), device=self.device).split(self.batch_size):
                keep = retention.calibration_scores(flat["memories"][batch], flat["type_ids"][batch],
                                                    flat["age"][batch], flat["usage"][batch],
                                                    flat["store_ids"][batch] if "store_ids" in flat else None)
                loss = self.calibration_coef * calibration_loss(keep, credit_t[batch], flat["mask"][batch] > 0.5)
                optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(retention.parameters(), self.max_grad_norm)
                optimizer.step()
                losses.append(float(loss.detach()))
        self.logger.record("train/calibration_loss", float(np.mean(losses)))
        self.logger.record("train/credited_banks", float((credit.sum(-1) > 0).mean()))


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
