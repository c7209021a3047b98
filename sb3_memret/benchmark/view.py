"""A task's controller observation, rebuilt from MIKASA's harness observation.

The harness hands a policy ``rgb`` (1, 128, 128, 6: the base camera's channels, then the wrist camera's) and
``proprio`` (1, 7), flattened by its wrapper chain. The project's controllers and writers read the task's own
layout (``agent/qpos``, ``agent/qvel``, ``extra/tcp_pose``, ``sensor_data/<camera>/rgb``, plus what the task's
detector reports), which the task's observation wrapper makes from ManiSkill's raw observation. ``HarnessView``
feeds that same wrapper a raw-layout observation assembled from the harness's images and the robot's own joint and
hand readings (proprioception, as ``proprio`` is), so the controller sees exactly what it sees in the project's
own envs; ``oracle_info`` and ``task_cue`` are never read.
"""

from __future__ import annotations

from typing import Any, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

CAMERAS = ("base_camera", "hand_camera")  # the order of their channels in the harness's ``rgb``


def raw_observation(env: gym.Env, obs: Mapping[str, Any]) -> dict[str, Any]:
    """ManiSkill's raw observation layout, from the harness's images and the robot's joints and hand pose."""
    rgb = obs["rgb"]
    if rgb.shape[-1] != 3 * len(CAMERAS):
        raise ValueError(f"the harness's rgb has {rgb.shape[-1]} channels; expected {3 * len(CAMERAS)} "
                         f"({' then '.join(CAMERAS)})")
    agent = env.unwrapped.agent
    return {
        "agent": {"qpos": agent.robot.get_qpos(), "qvel": agent.robot.get_qvel()},
        "extra": {"tcp_pose": agent.tcp.pose.raw_pose},
        "sensor_data": {camera: {"rgb": rgb[..., 3 * i:3 * i + 3]} for i, camera in enumerate(CAMERAS)},
    }


def _space(tree: Any) -> spaces.Space:
    if isinstance(tree, Mapping):
        return spaces.Dict({key: _space(value) for key, value in tree.items()})
    array = tree.detach().cpu().numpy() if hasattr(tree, "detach") else np.asarray(tree)
    if array.dtype == np.uint8:
        return spaces.Box(0, 255, array.shape, np.uint8)
    return spaces.Box(-np.inf, np.inf, array.shape, array.dtype)


class _RawSource(gym.Env):
    """The harness env as the task's observation wrapper expects to wrap it: the raw layout's space, and the
    harness's base env as ``unwrapped`` (its objects are what the task's detector reports)."""

    def __init__(self, harness_env: gym.Env, raw: Mapping[str, Any]):
        self._harness = harness_env
        self.observation_space = _space(raw)
        self.action_space = harness_env.action_space

    @property
    def unwrapped(self) -> Any:
        return self._harness.unwrapped


class HarnessView:
    """``observation(obs)``: the task's controller observation (numpy, batch of one) for a harness observation."""

    def __init__(self, task: Any, harness_env: gym.Env, obs: Mapping[str, Any]):
        from sb3_memret.common.obs_trees import to_numpy

        self.env, self._to_numpy = harness_env, to_numpy
        wrapper = getattr(task, "observation_wrapper", None)
        if wrapper is None:
            raise NotImplementedError(f"task {task.name!r} names no observation wrapper (observation_wrapper): "
                                      "its controller's view cannot be rebuilt from the harness's observation")
        self.wrapper = wrapper(_RawSource(harness_env, raw_observation(harness_env, obs)))

    def observation(self, obs: Mapping[str, Any]) -> dict[str, Any]:
        return self._to_numpy(self.wrapper.observation(raw_observation(self.env, obs)))


__all__ = ["CAMERAS", "HarnessView", "raw_observation"]
