"""DrawerRecall-v0: the decision-level recall task as a single gymnasium env.

One step is one decision: pick K memory slots, append their texts to the instruction, let
the frozen controller act for ``replan_every`` control steps, write what the simulator now
says into the bank. It is ``RecallVecEnv`` (``sb3_memret.envs.vec_env``) with one env
whose physics runs in this process, so a gymnasium user and the SB3 trainer play the same code.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from sb3_memret.envs.configs import MODES
from sb3_memret.envs.vec_env import recall_vec_env
from sb3_memret.memory.bank import MemoryBank

__all__ = ["DrawerRecallEnv", "MODES"]


class DrawerRecallEnv(gym.Env):
    """Retrieval decisions over a bounded language memory for a frozen controller (one env).

    Takes a run's flat ``env_kwargs`` (``sb3_memret.envs.configs.split_env_kwargs``: the task and its options,
    the controller, the memory's, the decisions' and the physics' fields); see ``RecallVecEnv`` for the modes,
    the action and the reward; its physics runs in this process. ``reset(options={"target_layer": L, "target": name})`` fixes the
    target's drawer (and, with several objects, the target).
    """

    metadata = {"render_modes": []}

    def __init__(self, **kwargs: Any):
        self.venv = recall_vec_env(1, **{**kwargs, "backend": "inprocess"})
        self.observation_space, self.action_space = self.venv.observation_space, self.venv.action_space

    @property
    def controller(self):
        return self.venv.controller

    @property
    def bank(self) -> MemoryBank:
        return self.venv.memories[0].bank

    @property
    def mode(self) -> str:
        return self.venv.mode

    def set_retention_weights(self, state_dict, age_unit: str) -> None:
        self.venv.set_retention_weights(state_dict, age_unit)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        env_seed = int(self.np_random.integers(2**31 - 1)) if seed is not None or self.venv.rngs[0] is None else None
        info = self.venv.reset_envs([0], [env_seed], [options or {}])[0]
        return self._obs(), info

    def step(self, action):
        observations, rewards, terminated, truncated, infos = self.venv.decide(np.asarray(action)[None])
        return observations[0], float(rewards[0]), bool(terminated[0]), bool(truncated[0]), infos[0]

    def _obs(self) -> dict[str, np.ndarray]:
        return self.venv.memories[0].observation()

    def instruction(self) -> str:
        return self.venv.memories[0].instruction()

    def true_slot(self) -> int:
        return self.venv.memories[0].true_slot()

    def close(self) -> None:
        self.venv.close()
