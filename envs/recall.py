"""DrawerRecall-v0: the decision-level env the memory learner acts in.

One step is one decision: pick K memory slots, append their texts to the instruction, let
the frozen controller act for ``replan_every`` control steps, write what the simulator now
says into the bank. The reward is the bank-blind shaped potential of the executed steps.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from sb3_memret.controllers import FrozenController, make_controller
from sb3_memret.envs.cabinet import check_layer
from sb3_memret.memory.bank import MemoryBank, importance_scorer
from sb3_memret.memory.encoder import EMBEDDING_DIM, MiniLMEncoder
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig, is_true_cube_memory, seed_memories
from sb3_memret.memory.writer import BoundingBoxPredicateExtractor, EventCompiler
from sb3_memret.policy.networks import RetentionScorer
from sb3_memret.prompts import INSTRUCTION, build_prompt, location_text
from sb3_memret.rewards import shaped_reward
from sb3_memret.rollout import execute_chunk, make_task_env, task_env_kwargs

MODES = ("recall", "oracle", "none")


class DrawerRecallEnv(gym.Env):
    """Retrieval decisions over a bounded language memory for a frozen controller.

    Modes: ``recall`` (the layer reaches the controller only through retrieved memories),
    ``oracle`` (the layer is in the instruction; retrieval is ignored) and ``none`` (the bare
    instruction). Action: ``MultiDiscrete([capacity] * k)``, ordered slots; an empty slot adds
    no text (``info["empty_slots"]`` counts them).

    Reward: (1 - gamma) * (gamma * Phi(s') - Phi(s)), s and s' the states before and after the
    executed control steps, plus ``success_bonus`` on success. Shaping at the decision level,
    with the gamma PPO discounts decisions by, makes the shaping telescope exactly, so it
    cannot change which retrieval policy is optimal (Ng et al., 1999); an undiscounted sum of
    per-control-step terms would instead penalise time spent near the goal.
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        mode: str = "recall",
        controller: str | FrozenController = "scripted",
        capacity: int = 6,
        k: int = 1,
        replan_every: int = 8,
        gamma: float = 0.97,
        success_bonus: float = 0.0,
        max_control_steps: int = 400,
        render_backend: str = "none",
        seeding: SeedingConfig | None = None,
        encoder: MiniLMEncoder | None = None,
        task_kwargs: dict[str, Any] | None = None,
    ):
        if mode not in MODES:
            raise ValueError(f"unknown mode {mode!r}; expected one of {list(MODES)}")
        if not 1 <= k <= capacity:
            raise ValueError(f"k must be in [1, capacity={capacity}], got {k}")

        self.mode, self.capacity, self.k = mode, capacity, k
        self.replan_every, self.gamma, self.success_bonus = replan_every, gamma, success_bonus
        self.controller = make_controller(controller) if isinstance(controller, str) else controller
        if not 1 <= replan_every <= self.controller.spec.chunk_len:
            raise ValueError(f"replan_every must be in [1, {self.controller.spec.chunk_len}], got {replan_every}")
        task_kwargs = {**task_env_kwargs(self.controller, render_backend), **(task_kwargs or {})}
        self.task = make_task_env(max_episode_steps=max_control_steps, **task_kwargs)
        self.controller.check_env(self.task)
        self.seeding = seeding or SeedingConfig()
        self.encoder = encoder or MiniLMEncoder()
        self.extractor = BoundingBoxPredicateExtractor()
        self.compiler = EventCompiler(self.encoder)
        self.bank = MemoryBank(capacity)
        self.retention: RetentionScorer | None = None

        self.action_space = spaces.MultiDiscrete([capacity] * k)
        self.observation_space = spaces.Dict(
            instruction=spaces.Box(-1.0, 1.0, (EMBEDDING_DIM,), np.float32),
            memories=spaces.Box(-1.0, 1.0, (capacity, EMBEDDING_DIM), np.float32),
            mask=spaces.Box(0.0, 1.0, (capacity,), np.float32),
            type_ids=spaces.Box(0.0, len(MemoryType) - 1, (capacity,), np.float32),
            age=spaces.Box(0.0, np.inf, (capacity,), np.float32),
            usage=spaces.Box(0.0, np.inf, (capacity,), np.float32),
        )
        self._obs: Any = None
        self._phi = np.zeros(1)  # staged potential of the current state
        self._t = 0
        self._layer = 1
        self._true_evicted = False

    # ------------------------------------------------------------ retention
    def set_retention_weights(self, state_dict: dict[str, torch.Tensor]) -> None:
        """Use these retention-network weights for eviction (pushed by the trainer each rollout)."""
        if self.retention is None:
            self.retention = RetentionScorer()
        self.retention.load_state_dict(state_dict)
        self.retention.eval()

    def keep_scores(self, entries: list[MemoryEntry]) -> np.ndarray:
        if self.retention is None:
            return importance_scorer(entries)
        with torch.no_grad():
            mem = torch.as_tensor(np.stack([e.embedding for e in entries]))[None]
            types = torch.tensor([[int(e.type) for e in entries]])
            age = torch.tensor([[float(self._t - e.timestamp) for e in entries]])
            usage = torch.tensor([[float(e.usage_count) for e in entries]])
            return self.retention(mem, types, age, usage)[0].numpy()

    def _write(self, entries: list[MemoryEntry]) -> None:
        for entry in entries:
            outcome = self.bank.write(entry, self.keep_scores)
            if outcome.evicted is not None and is_true_cube_memory(outcome.evicted, self._layer):
                self._true_evicted = True

    # ------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        task_seed = int(self.np_random.integers(2**31 - 1))
        self._obs, task_info = self.task.reset(seed=task_seed, options=options)
        self._phi = task_info["potential"].numpy()
        state = self.task.unwrapped.privileged_state()
        self._layer = check_layer(int(state.cube_layer[0]))
        self.controller.reset([task_seed])
        self._t, self._true_evicted = 0, False
        self.bank.clear()
        seeds = seed_memories(self._layer, self.np_random, self.seeding)
        vectors = self.encoder.encode([e.text for e in seeds])
        self._write([e.with_embedding(v) for e, v in zip(seeds, vectors)])
        self.compiler.reset()
        self.compiler.update(self.extractor.extract(state), 0)  # the seeded bank is the t=0 memory
        return self._observation(), self._info(state, success=False)

    def step(self, action):
        slots = np.asarray(action, dtype=np.int64).reshape(-1)
        if slots.shape != (self.k,) or (slots < 0).any() or (slots >= self.capacity).any():
            raise ValueError(f"action must be {self.k} slot indices in [0, {self.capacity}), got {action!r}")
        entries = self.bank.entries
        decision_true_slot = self.true_slot()
        chosen = [entries[s] for s in slots if s < len(entries)]
        for s in slots[slots < len(entries)]:
            self.bank.mark_used(int(s))
        prompt = self._prompt(chosen)
        outcome = execute_chunk(self.task, self.controller.act(self._obs, [prompt])[0][: self.replan_every])
        phi = self._phi
        self._obs, self._t, info = outcome.obs, self._t + outcome.steps, outcome.info
        terminated, truncated = outcome.terminated, outcome.truncated
        self._phi = info["potential"].numpy()
        reward = (1.0 - self.gamma) * float(shaped_reward(phi, self._phi, self.gamma)[0])
        success = bool(info["success"][0])
        if success:
            reward += self.success_bonus
        state = self.task.unwrapped.privileged_state()
        self._write(self.compiler.update(self.extractor.extract(state), self._t))
        self.bank.age(self._t)
        out = self._info(state, success)
        out.update(prompt=prompt, decision_true_slot=decision_true_slot,
                   retrieved_true=any(is_true_cube_memory(e, self._layer) for e in chosen),
                   empty_slots=int(self.k - len(chosen)))
        return self._observation(), reward, terminated, truncated and not terminated, out

    def close(self) -> None:
        self.task.close()

    # ------------------------------------------------------------ helpers
    def _prompt(self, chosen: list[MemoryEntry]) -> str:
        template = self.controller.spec.prompt_template
        if self.mode == "oracle":
            return build_prompt(INSTRUCTION, [location_text("cube", self._layer)], template)
        if self.mode == "none":
            return build_prompt(INSTRUCTION, [], template)
        return build_prompt(INSTRUCTION, [e.text for e in chosen], template)

    def instruction(self) -> str:
        return build_prompt(INSTRUCTION, [location_text("cube", self._layer)]) if self.mode == "oracle" else INSTRUCTION

    def true_slot(self) -> int:
        return next((i for i, e in enumerate(self.bank.entries) if is_true_cube_memory(e, self._layer)), -1)

    def _observation(self) -> dict[str, np.ndarray]:
        view = self.bank.view()
        return {
            "instruction": self.encoder.encode_one(self.instruction()).astype(np.float32),
            "memories": view.embeddings,
            "mask": view.mask.astype(np.float32),
            "type_ids": view.type_ids.astype(np.float32),
            "age": view.age,
            "usage": view.usage,
        }

    def _info(self, state, success: bool) -> dict[str, Any]:
        return {
            "true_slot": self.true_slot(),
            "true_evicted": self._true_evicted,
            "success": success,
            "cube_layer": self._layer,
            "memory_texts": [e.text for e in self.bank.entries],
        }
