"""One memory learner across several tasks: their decision envs as one batch.

``MultiTaskVecEnv`` puts one ``RecallVecEnv`` per task side by side, envs ``offsets[j] .. offsets[j+1]`` playing
task ``j``. Every task's env has the same observation and action space (the bank's slots, K), so one retriever and
one retention critic serve them all; what tells the tasks apart is the instruction, which the observation carries.
Each task keeps its own frozen controller (a controller name is made per task: ``scripted`` is each task's
expert), its own writer, decoys and env settings (``tasks: {name: {...}}`` in a run's ``env_kwargs``), and its
own held-out seeds. An env's ``info["group"]`` is its task's name, so held-out success is reported per task
(the task's own group, a cue's colour, is ``info["task_group"]``).
"""

from __future__ import annotations

import copy
from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvStepReturn

from sb3_memret.envs.vec_env import RecallVecEnv, make_recall_vec_env, recall_vec_env


class MultiTaskVecEnv(VecEnv):
    """Several tasks' ``RecallVecEnv``s (``parts``) as one VecEnv; ``parts`` must share their spaces and the
    unit of a memory's age (one policy reads them all)."""

    def __init__(self, parts: Sequence[RecallVecEnv]):
        if len(parts) < 2:
            raise ValueError(f"a learner across tasks needs two or more tasks' envs, got {len(parts)}")
        first = parts[0]
        for part in parts[1:]:
            for what in ("observation_space", "action_space", "age_unit"):
                if getattr(part, what) != getattr(first, what):
                    raise ValueError(f"task {part.task.name!r} and task {first.task.name!r} differ in {what} "
                                     f"({getattr(part, what)} vs {getattr(first, what)}): one learner needs the "
                                     "same capacity, k, observe_potential and age_unit for every task")
        names = [part.task.name for part in parts]
        if len(set(names)) != len(names):
            raise ValueError(f"each task once: {names}")
        self.parts = list(parts)
        self.offsets = np.concatenate([[0], np.cumsum([part.num_envs for part in parts])]).astype(int)
        self.age_unit = first.age_unit
        super().__init__(int(self.offsets[-1]), first.observation_space, first.action_space)

    @property
    def task_names(self) -> list[str]:
        return [part.task.name for part in self.parts]

    @property
    def physics_restarts(self) -> int:
        """Physics workers that died and were restarted (Ray), across the tasks."""
        return sum(part.physics_restarts for part in self.parts)

    def _slices(self) -> list[slice]:
        return [slice(int(a), int(b)) for a, b in zip(self.offsets[:-1], self.offsets[1:])]

    def _concat(self, observations: Sequence[Mapping[str, np.ndarray]]) -> dict[str, np.ndarray]:
        return {key: np.concatenate([obs[key] for obs in observations]) for key in observations[0]}

    def _tagged(self, part: RecallVecEnv, info: dict[str, Any]) -> dict[str, Any]:
        if "group" in info:
            info["task_group"] = info["group"]
        info["group"] = part.task.name
        return info

    # ------------------------------------------------------------ trainer-side methods (``env_method``)
    def set_retention_weights(self, state_dict: Mapping[str, Any], age_unit: str) -> None:
        for part in self.parts:
            part.set_retention_weights(dict(state_dict), age_unit)

    def set_task_seeds(self, per_env: Sequence[Sequence[int]]) -> None:
        """Env ``i`` starts its next episodes at ``per_env[i]`` (as ``RecallVecEnv.set_task_seeds``)."""
        if len(per_env) != self.num_envs:
            raise ValueError(f"per_env must list task seeds for each of the {self.num_envs} envs, got {len(per_env)}")
        for part, rows in zip(self.parts, self._slices()):
            part.set_task_seeds(list(per_env[rows]))

    def held_out_seed_blocks(self, counts: Sequence[int], kind: str) -> list[list[int]] | None:
        """Per env, the task seeds of its ``counts[i]`` held-out episodes: each task's own ``kind`` seeds
        (``RecallVecEnv.held_out_seed_blocks``); None when no task has such seeds."""
        blocks = [part.held_out_seed_blocks(list(counts[rows]), kind) for part, rows in zip(self.parts, self._slices())]
        if all(block is None for block in blocks):
            return None
        if any(block is None for block in blocks):
            missing = [part.task.name for part, block in zip(self.parts, blocks) if block is None]
            raise ValueError(f"tasks {missing} have no {kind} seeds while the others have")
        return [seeds for block in blocks for seeds in block]

    # ------------------------------------------------------------ VecEnv API
    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Env ``i`` is seeded with ``seed + i`` across the tasks."""
        return [s for part, start in zip(self.parts, self.offsets) for s in
                part.seed(None if seed is None else seed + int(start))]

    def reset(self) -> dict[str, np.ndarray]:
        observations = [part.reset() for part in self.parts]
        self.reset_infos = [self._tagged(part, info) for part in self.parts for info in part.reset_infos]
        return self._concat(observations)

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        if len(actions) != self.num_envs:
            raise ValueError(f"expected actions for {self.num_envs} envs, got {len(actions)}")
        for part, rows in zip(self.parts, self._slices()):
            part.step_async(actions[rows])

    def step_wait(self) -> VecEnvStepReturn:
        observations, rewards, dones, infos = [], [], [], []
        for part in self.parts:
            obs, reward, done, info = part.step_wait()
            observations.append(obs)
            rewards.append(reward)
            dones.append(done)
            infos.extend(self._tagged(part, i) for i in info)
        return self._concat(observations), np.concatenate(rewards), np.concatenate(dones), infos

    def close(self) -> None:
        errors = []
        for part in self.parts:
            try:
                part.close()
            except Exception as err:  # close every task's physics, then say what failed
                errors.append(err)
        if errors:
            raise errors[0]

    def _part_of(self, index: int) -> RecallVecEnv:
        return self.parts[int(np.searchsorted(self.offsets, index, side="right")) - 1]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """An attribute of each env's task env (``render_mode`` None: nothing renders)."""
        return [self._part_of(i).get_attr(attr_name)[0] for i in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for part in {self._part_of(i) for i in self._get_indices(indices)}:
            part.set_attr(attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        """Methods act on the trainer-side state once, as ``RecallVecEnv``'s (``set_retention_weights``,
        ``set_task_seeds``)."""
        if not hasattr(type(self), method_name):
            raise AttributeError(f"a learner across tasks has no env method {method_name!r}; it has "
                                 "set_retention_weights, set_task_seeds and held_out_seed_blocks")
        result = getattr(self, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]


def task_env_kwargs(env_kwargs: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Each task's flat ``env_kwargs`` from a learner's across tasks: the shared ones, then the task's own
    (``tasks: {name: {...}}``; a list gives each task the shared ones alone)."""
    shared = {key: value for key, value in env_kwargs.items() if key != "tasks"}
    tasks = env_kwargs["tasks"]
    own = tasks if isinstance(tasks, Mapping) else {name: {} for name in tasks}
    return {name: {**shared, **(settings or {}), "task": name} for name, settings in own.items()}


def multi_task_vec_env(envs_per_task: int, env_kwargs: Mapping[str, Any]) -> MultiTaskVecEnv:
    """``MultiTaskVecEnv`` with ``envs_per_task`` envs of each task of ``env_kwargs["tasks"]``. A controller given
    by name is made for each task; a controller object (one that reads every task's prompts) is shared by weight,
    each task's envs holding a shallow copy, so their episodes' state stays apart. One sentence encoder serves
    every task."""
    from sb3_memret.memory.encoder import MiniLMEncoder

    per_task = task_env_kwargs(env_kwargs)
    encoder = env_kwargs.get("encoder") or MiniLMEncoder()
    parts: list[RecallVecEnv] = []
    try:
        for name, kwargs in per_task.items():
            controller = kwargs.get("controller", "scripted")
            kwargs = {**kwargs, "encoder": encoder,
                      "controller": controller if isinstance(controller, str) else copy.copy(controller)}
            parts.append(recall_vec_env(envs_per_task, **kwargs))
        return MultiTaskVecEnv(parts)
    except BaseException:
        for part in parts:
            part.close()
        raise


def make_multi_task_vec_env(envs_per_task: int, env_kwargs: Mapping[str, Any], seed: int | None = None,
                            backend: str = "auto", ray_address: str | None = None) -> VecMonitor:
    """``multi_task_vec_env`` behind a ``VecMonitor``; env ``i`` (across the tasks) is seeded with ``seed + i``."""
    if envs_per_task < 1:
        raise ValueError(f"n_envs (per task) must be >= 1, got {envs_per_task}")
    venv = multi_task_vec_env(envs_per_task, {**env_kwargs, "backend": backend, "ray_address": ray_address})
    if seed is not None:
        venv.seed(seed)
    return VecMonitor(venv)


def make_decision_vec_env(n_envs: int, env_kwargs: Mapping[str, Any], seed: int | None = None, backend: str = "auto",
                          ray_address: str | None = None) -> VecMonitor:
    """A run's decision envs from its flat ``env_kwargs``: one task's ``n_envs`` envs (``make_recall_vec_env``), or
    ``n_envs`` per task of a learner across tasks (``tasks``)."""
    if "tasks" in env_kwargs:
        return make_multi_task_vec_env(n_envs, env_kwargs, seed, backend, ray_address)
    return make_recall_vec_env(n_envs, dict(env_kwargs), seed, backend, ray_address)


__all__ = ["MultiTaskVecEnv", "make_decision_vec_env", "make_multi_task_vec_env", "multi_task_vec_env",
           "task_env_kwargs"]
