"""RecallVecEnv: N recall envs served by ONE frozen controller call per decision round.

The memory banks, writers, encoder, retention critic and the frozen controller live here, in
the trainer process; the task physics runs in a backend (``sb3_memret.physics``): worker
processes on the CPU, one batched ManiSkill env on the GPU, or Ray actors. One decision round::

    slots (N, K) ──banks──▶ N prompts ──controller.act(obs[N], prompts[N])──▶ chunks (N, H, 7)
      ──physics: replan_every steps in every env──▶ frames ──writers──▶ banks, rewards, infos

With ``replans_per_decision`` R > 1 the controller replans R times (each from the new observation,
with the same prompt) before the retriever decides again: memory is consulted less often than the
controller acts, so one retrieval's effect on the episode is larger and easier to credit. With
``retrieve_on_write`` a decision also ends at the replan in which its env's writer added a fact: the
bank changed, so the retriever chooses again (a prompt chosen before a cue was seen does not outlive it).

Episodes that end are reset at once (SB3's auto-reset: ``info["terminal_observation"]``), each
env drawing its next episode from its own generator, seeded by ``seed(s)`` as ``s + i``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.utils import seeding as gym_seeding
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvStepReturn

from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers import FrozenController
from sb3_memret.controllers.pacing import replan_interval
from sb3_memret.envs.configs import DecisionConfig, MemoryConfig, PhysicsConfig, check_mode, split_env_kwargs
from sb3_memret.envs.recall_memory import EpisodeMemory, observation_space
from sb3_memret.memory.bank import importance_scorer
from sb3_memret.memory.encoder import MiniLMEncoder
from sb3_memret.memory.stores import units_per_timescale
from sb3_memret.memory.schema import MemoryEntry
from sb3_memret.common.obs_trees import stack_obs
from sb3_memret.common.seeds import held_out_seeds
from sb3_memret.physics import make_physics
from sb3_memret.physics.backends import PhysicsBackend, ResetRequest
from sb3_memret.policy.networks import RetentionScorer
from sb3_memret.tasks.rewards import absorbing_success_value, shaped_reward
from sb3_memret.evaluation.rollout import task_env_kwargs
from sb3_memret.tasks import Task, make_task
from sb3_memret.tasks.base import EnvFrame
from sb3_memret.common.workers import torch_threads


class RecallVecEnv(VecEnv):
    """Retrieval decisions over a bounded language memory for a frozen controller on any ``task``,
    ``num_envs`` at once.

    Modes: ``recall`` (what the controller must know, the drawer's layer or a cue's colour, reaches it
    only through retrieved memories), ``oracle`` (the task's true facts are in the prompt; retrieval is
    ignored) and ``none`` (the bare instruction). Action per env: ``MultiDiscrete([capacity] * k)``, ordered slots; an empty slot
    adds no text (``info["empty_slots"]`` counts them).

    Reward: (1 - gamma) * (gamma * Phi(s') - Phi(s)), s and s' the states before and after the
    executed control steps, plus ``success_bonus`` on success (a task without a potential Phi, as
    MIKASA's, gives its env's own reward summed over the steps instead of the shaping term). Shaping at the decision level,
    with the gamma PPO discounts decisions by, telescopes exactly, so it cannot change which
    retrieval policy is optimal (Ng et al., 1999). A task that ends its episodes at success
    (``Task.ends_at_success``) stands for an env that would run on in an absorbing success: the decision
    that succeeds also earns what the cut-off steps would have paid (``absorbing_success_value``), so an
    early success never pays less than failing slowly.

    The controller replans every ``replan_every`` control steps (None: the task's, ``Task.replan_every``).
    With ``replans_per_decision`` R, a decision holds its prompt for R replans (R * replan_every steps);
    its reward sums the env's reward over them (or shapes from the first state to the last). With
    ``retrieve_on_write`` an env's decision ends early at the replan whose frames wrote a fact to its bank.

    What the env is made of comes in three frozen configs (``sb3_memret.envs.configs``): ``memory`` (capacity,
    a long-term store, where facts come from, what evicts, ages, decoys), ``decisions`` (mode, k, replanning,
    the reward's gamma and bonus, tasks per learning episode, the observed potential) and ``physics`` (where
    the task envs run and what renders). The ``task`` owns its own options: the drawer's objects (several
    hidden, the instruction naming the target, so the retriever must read it) and its households.
    ``controller_calls`` counts ``controller.act`` calls: one per replan round (R per decision round).

    ``memory.source="observed"``: the facts come only from what the robot saw, in an observation phase before the
    episode (``Task.look_in``; the drawer opens each drawer once). ``memory.long_term_capacity > 0``: each env is
    a household (``Task.new_household``: the drawer's objects stay in their drawers across episodes and are
    sometimes rearranged); a long-term store of that many slots, before the per-episode slots, keeps what the
    robot saw across episodes. ``decisions.tasks_per_episode``: tasks (each a reset of the
    physics, ``info["task_done"]``) per learning episode, so that what memory keeps for a later task is
    credited to the decisions that kept it; a learning episode ends as a time-limit truncation.

    ``decisions.observe_potential``: each observation also carries ``potential``, (1 - gamma) * Phi(s) of the
    state the decision is taken in, so the critic need not explain the shaping from memories alone
    (``MemoryRetrievalPolicy``). A finished task's potential was paid in full by its last reward, so its
    terminal observation carries the next task's starting potential, from which the household goes on.
    ``memory.age_unit``: the memories' ages the observation carries (and the critic evicts by), in control
    steps or in tasks; the policy must read the same unit (its ``age_unit``).
    """

    def __init__(self, num_envs: int, task: str | Task, controller: str | FrozenController = "scripted",
                 memory: MemoryConfig = MemoryConfig(), decisions: DecisionConfig = DecisionConfig(),
                 physics: PhysicsConfig = PhysicsConfig(), encoder: MiniLMEncoder | None = None):
        self.task = make_task(task)
        self.task.check_options(observed=memory.source == "observed", household=memory.household,
                                observe_potential=decisions.observe_potential)
        self.memory_config, self.decisions, self.physics_config = memory, decisions, physics
        self.tasks_per_episode = decisions.tasks_per_episode
        if not decisions.k <= memory.slots:
            raise ValueError(f"k must be in [1, slots={memory.slots}], got {decisions.k}")
        self.mode, self.slots, self.k = decisions.mode, memory.slots, decisions.k
        self.gamma, self.success_bonus = decisions.gamma, decisions.success_bonus
        if self.task.ends_at_success and self.task.success_reward is None:
            raise ValueError(f"task {self.task.name!r} ends its episodes at success but sets no success_reward: "
                             "the reward its env pays at each step after success is needed to value the cut-off steps")
        self.max_control_steps = decisions.max_control_steps or self.task.max_control_steps
        self.controller = make_controller(controller, self.task) if isinstance(controller, str) else controller
        self.replan_every = replan_interval(self.task, decisions.replan_every, self.controller)
        self.replans_per_decision, self.retrieve_on_write = decisions.replans_per_decision, decisions.retrieve_on_write
        task_kwargs = {**task_env_kwargs(self.controller, physics.render_backend, self.task), **physics.task_kwargs}
        self.encoder = encoder or MiniLMEncoder()
        self.retention: RetentionScorer | None = None
        self.observe_potential = decisions.observe_potential
        self.age_unit = memory.age_units
        self.timescales = [spec.timescale for spec in memory.store_specs]
        super().__init__(num_envs, observation_space(self.slots, self.observe_potential, len(self.timescales) > 1),
                         spaces.MultiDiscrete([self.slots] * self.k))
        self.households = [self.task.new_household() for _ in range(num_envs)] if memory.household else None
        self.physics: PhysicsBackend = make_physics(physics.backend, num_envs, task_kwargs, self.max_control_steps,
                                                    physics.ray_address, task=self.task)
        try:
            self.controller.check_env(self.physics.env_info)
        except ValueError:
            self.physics.close()
            raise
        template = self.controller.spec.prompt_template
        self.memories = [EpisodeMemory(memory, self.mode, self.encoder, self.keep_scores, template, self.task)
                         for _ in range(num_envs)]
        self.rngs: list[np.random.Generator | None] = [None] * num_envs
        self.task_seed_queues: list[list[int]] = [[] for _ in range(num_envs)]
        self.episode_task_seeds: list[int | None] = [None] * num_envs  # the seed each env's episode started from
        self.frames: list[EnvFrame | None] = [None] * num_envs
        self.episode_steps = np.zeros(num_envs, dtype=np.int64)  # control steps each env's episode has run
        self.controller_calls = 0
        self.tasks_played = np.zeros(num_envs, dtype=np.int64)
        self.closed = False
        self._actions: np.ndarray | None = None
        self._controller_batch = False  # whether controller.reset has set up the batch of num_envs

    # ------------------------------------------------------------ retention
    def set_retention_weights(self, state_dict: dict[str, torch.Tensor], age_unit: str | Mapping[str, str]) -> None:
        """Use these retention-network weights for eviction (pushed by the trainer each rollout); the
        network reads ages in ``age_unit`` (one, or one per store's timescale), which must be the units this env
        observes."""
        if units_per_timescale(age_unit, self.timescales) != units_per_timescale(self.age_unit, self.timescales):
            raise ValueError(f"the retention critic reads ages in {age_unit!r}, but this env counts them in "
                             f"{self.age_unit!r}: build the env (or its stores) with those age units")
        if self.retention is None:
            self.retention = RetentionScorer(age_unit=age_unit, stores=len(self.timescales) > 1)
        self.retention.load_state_dict(state_dict)
        self.retention.eval()

    def keep_scores(self, entries: Sequence[MemoryEntry], ages: np.ndarray, timescale: int | None) -> np.ndarray:
        """The retention critic's keep-scores of one store's ``entries`` of these ``ages`` (in the store's unit),
        told the store's ``timescale`` id (None: a memory of one store); the type prior before any push."""
        if self.retention is None:
            return importance_scorer(entries)
        return self.retention.score_entries(entries, ages, timescale)

    @property
    def physics_restarts(self) -> int:
        """Physics workers that died and were restarted with their episode replayed (Ray), so far."""
        return len(getattr(self.physics, "restarts", ()))

    # ------------------------------------------------------------ episodes
    def set_mode(self, mode: str) -> None:
        """Play the episodes each env starts from now on in ``mode`` (``recall``, ``oracle`` or ``none``): one
        set of physics workers serves several conditions, one after another. An episode under way keeps its mode."""
        self.mode = check_mode(mode)

    def set_task_seeds(self, per_env: Sequence[Sequence[int]]) -> None:
        """Seed the task env's next episodes explicitly (a benchmark's evaluation seeds): env ``i`` starts its
        next ``len(per_env[i])`` episodes at these seeds, then draws from its generator again. The memory's
        own randomness (decoys) still comes from the env's generator."""
        if len(per_env) != self.num_envs:
            raise ValueError(f"per_env must list task seeds for each of the {self.num_envs} envs, got {len(per_env)}")
        for seeds in per_env:
            bad = [s for s in seeds if not isinstance(s, (int, np.integer)) or not 0 <= s < 2**32]
            if bad:
                raise ValueError(f"task seeds must be integers in [0, 2**32), got {bad!r}")
        self.task_seed_queues = [[int(s) for s in seeds] for seeds in per_env]

    def held_out_seed_blocks(self, counts: Sequence[int], kind: str) -> list[list[int]] | None:
        """Per env, the task seeds of its ``counts[i]`` held-out episodes: contiguous blocks of the task's ``kind``
        seeds ("evaluation": its benchmark protocol's; "development": those to choose checkpoints on), or None
        where the task has none (the evaluation seed then decides)."""
        if len(counts) != self.num_envs:
            raise ValueError(f"counts must give each of the {self.num_envs} envs its episodes, got {len(counts)}")
        seeds = held_out_seeds(self.task, kind, int(sum(counts)))
        if seeds is None:
            return None
        starts = np.concatenate([[0], np.cumsum(counts)]).astype(int)
        return [list(seeds[starts[i]:starts[i + 1]]) for i in range(self.num_envs)]

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int | None] | None = None,
                   options: Sequence[dict[str, Any]] | None = None) -> dict[int, dict[str, Any]]:
        """Start new episodes in ``env_ids``: a ``seeds`` entry reseeds that env's generator (None
        continues it); ``options`` go to the task's reset (e.g. ``{"target_layer": 2}``). Returns the
        reset infos by env id."""
        seeds = list(seeds) if seeds is not None else [None] * len(env_ids)
        options = list(options) if options is not None else [{}] * len(env_ids)
        if self.households is not None and any(options):
            raise ValueError(f"a household decides where its objects are; reset options {options!r} are not accepted")
        requests, moved = [], {}
        for i, seed, opts in zip(env_ids, seeds, options):
            if seed is not None or self.rngs[i] is None:
                self.rngs[i], _ = gym_seeding.np_random(seed)
            opts = dict(opts or {})
            if self.households is not None:
                placement, target, moved[i] = self.households[i].next_episode(self.rngs[i])
                opts = {"placement": placement, "target": target}
            task_seed = int(self.rngs[i].integers(2**31 - 1))
            if self.task_seed_queues[i]:
                task_seed = self.task_seed_queues[i].pop(0)
            requests.append(ResetRequest(i, task_seed, opts))
        frames = self.physics.reset(requests)
        task_seeds = [r.seed for r in requests]
        if self._controller_batch:
            self.controller.reset_envs(list(env_ids), task_seeds)
        else:
            if len(env_ids) != self.num_envs:
                raise RuntimeError("the first reset must start every env")
            by_env = dict(zip(env_ids, task_seeds))
            self.controller.reset([by_env[i] for i in range(self.num_envs)])
            self._controller_batch = True
        infos = {}
        for request in requests:
            i, frame = request.env_id, frames[request.env_id]
            self.frames[i], self.episode_task_seeds[i] = frame, request.seed
            self.episode_steps[i] = 0
            self.memories[i].mode = self.mode
            self.memories[i].start(frame, self.rngs[i], moved.get(i, False))
            infos[i] = {**self.memories[i].info(success=False), "task_seed": request.seed}
        return infos

    def decide(self, actions: np.ndarray) -> tuple[list[dict], np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """One decision round without auto-reset: observations, rewards, terminated, truncated, infos."""
        actions = np.asarray(actions, dtype=np.int64).reshape(self.num_envs, -1)
        if actions.shape[1] != self.k or (actions < 0).any() or (actions >= self.slots).any():
            raise ValueError(f"actions must be {self.k} slot indices in [0, {self.slots}) per env, "
                             f"got {actions.tolist()!r}")
        if any(frame is None for frame in self.frames):
            raise RuntimeError("reset the envs before stepping them")
        true_slots, chosen, prompts = [], [], []
        for memory, slots in zip(self.memories, actions):
            true_slots.append(memory.true_slots() if memory.facts_in_bank() else [])
            chosen.append(memory.choose(slots))
            prompts.append(memory.prompt(chosen[-1]))
        starts, rewards = list(self.frames), np.zeros(self.num_envs, dtype=np.float32)
        decision_steps = np.zeros(self.num_envs, dtype=np.int64)
        running = list(range(self.num_envs))
        for _ in range(self.replans_per_decision):  # the same prompts, each replan from the newest observation
            with torch_threads(1 if self.physics.shares_cores else None):
                chunks = self.controller.act(stack_obs([frame.obs for frame in self.frames]), prompts)
            self.controller_calls += 1
            frames = self.physics.execute({i: chunks[i, : self.replan_every] for i in running})
            wrote = set()
            for i in running:
                self.frames[i] = frames[i]
                if self.memories[i].observe(frames[i]):
                    wrote.add(i)
                rewards[i] += frames[i].reward
                decision_steps[i] += frames[i].steps
            running = [i for i in running if not (frames[i].terminated or frames[i].truncated
                                                  or (self.retrieve_on_write and i in wrote))]
            if not running:
                break
        terminated, truncated = np.zeros(self.num_envs, bool), np.zeros(self.num_envs, bool)
        observations, infos = [], []
        for i, memory in enumerate(self.memories):
            frame = dataclasses.replace(self.frames[i], reward=float(rewards[i]))
            self.episode_steps[i] += decision_steps[i]
            rewards[i] = self._reward(starts[i], frame, self.episode_steps[i], decision_steps[i])
            terminated[i], truncated[i] = frame.terminated, frame.truncated and not frame.terminated
            info = memory.info(frame.success)
            info.update(prompt=prompts[i], decision_true_slots=true_slots[i], task_seed=self.episode_task_seeds[i],
                        retrieved_true=memory.retrieved_true(chosen[i]), empty_slots=int(self.k - len(chosen[i])))
            observations.append(self._observation(i))
            infos.append(info)
        return observations, rewards, terminated, truncated, infos

    def _reward(self, before: EnvFrame, frame: EnvFrame, episode_steps: int, decision_steps: int) -> float:
        """(1 - gamma) times the shaping term of the task's potential (or, for a task without one, the env's
        own reward summed over the chunk), plus the success bonus; an episode that ended at its success
        also earns what its cut-off steps would have paid."""
        if frame.potential is None:
            reward = frame.reward
        else:
            reward = float(shaped_reward(np.array([before.potential]), np.array([frame.potential]), self.gamma)[0])
        reward = (1.0 - self.gamma) * reward + (self.success_bonus if frame.success else 0.0)
        if self.task.ends_at_success and frame.success and frame.terminated:
            steps_per_decision = self.replan_every * self.replans_per_decision
            reward += absorbing_success_value(self.task.success_reward, max(self.max_control_steps - episode_steps, 0),
                                              max(steps_per_decision - decision_steps, 0), steps_per_decision,
                                              self.gamma)
        return reward

    def _observation(self, i: int) -> dict[str, np.ndarray]:
        """Env ``i``'s decision observation: its memory's, with the shaping potential if observed."""
        observation = self.memories[i].observation()
        if self.observe_potential:
            observation["potential"] = np.array([(1.0 - self.gamma) * self.frames[i].potential], dtype=np.float32)
        return observation

    # ------------------------------------------------------------ VecEnv API
    def reset(self) -> dict[str, np.ndarray]:
        infos = self.reset_envs(range(self.num_envs), self._seeds, self._options)
        self.reset_infos = [infos[i] for i in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return self._stack([self._observation(i) for i in range(self.num_envs)])

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async()")
        observations, rewards, terminated, truncated, infos = self.decide(self._actions)
        self._actions = None
        task_done = terminated | truncated
        self.tasks_played += task_done
        # a household's learning episode spans tasks_per_episode tasks: memory kept for later tasks earns its reward
        dones = task_done & (self.tasks_played % self.tasks_per_episode == 0)
        done_ids = [i for i in range(self.num_envs) if task_done[i]]
        for i in done_ids:
            infos[i]["task_done"] = True
            if dones[i]:
                infos[i]["terminal_observation"] = observations[i]
                infos[i]["TimeLimit.truncated"] = bool(truncated[i]) or self.tasks_per_episode > 1
        if done_ids:
            reset_infos = self.reset_envs(done_ids)
            for i in done_ids:
                self.reset_infos[i] = reset_infos[i]
                observations[i] = self._observation(i)
                if dones[i] and self.observe_potential:
                    infos[i]["terminal_observation"]["potential"] = observations[i]["potential"]
        return self._stack(observations), rewards, dones, infos

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.physics.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Attributes are shared by every env of the batch (``render_mode`` is None: nothing renders)."""
        value = None if attr_name == "render_mode" else getattr(self, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        """Methods act on the shared trainer-side state once (e.g. ``set_retention_weights``)."""
        result = getattr(self, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def _stack(self, observations: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
        return {key: np.stack([obs[key] for obs in observations]) for key in observations[0]}


def recall_vec_env(num_envs: int = 1, **env_kwargs: Any) -> RecallVecEnv:
    """``RecallVecEnv`` from a run's flat ``env_kwargs`` (``sb3_memret.envs.configs.split_env_kwargs``)."""
    task, rest, memory, decisions, physics = split_env_kwargs(env_kwargs)
    return RecallVecEnv(num_envs, task, memory=memory, decisions=decisions, physics=physics, **rest)


def make_recall_vec_env(n_envs: int = 1, env_kwargs: dict[str, Any] | None = None, seed: int | None = None,
                        backend: str = "auto", ray_address: str | None = None) -> VecMonitor:
    """``RecallVecEnv`` with ``n_envs`` envs behind a ``VecMonitor`` (episode return/length logs), from a run's
    flat ``env_kwargs``. Env ``i`` is seeded with ``seed + i``; ``backend`` and ``ray_address`` place the physics
    (``sb3_memret.physics.make_physics``)."""
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    venv = recall_vec_env(n_envs, **{**dict(env_kwargs or {}), "backend": backend, "ray_address": ray_address})
    if seed is not None:
        venv.seed(seed)
    return VecMonitor(venv)


__all__ = ["RecallVecEnv", "make_recall_vec_env", "recall_vec_env"]
