"""What the agent's parts see of MIKASA's harness: the policy side's view, and a privileged controller's.

The harness hands a policy ``rgb`` (1, 128, 128, 6: the base camera's channels, then the wrist camera's) and
``proprio`` (1, 7: the hand's xyz and roll-pitch-yaw, the gripper's opening), and the instruction. The project's
writers and controllers read the task's own layout (``agent/qpos``, ``extra/tcp_pose``, ``sensor_data/<camera>/rgb``).

- ``policy_view`` rebuilds that layout from the harness's observation alone: the cameras, the hand's pose (its
  quaternion from the roll-pitch-yaw) and the two fingers (half the gripper's opening each); the arm's joints are NaN
  and nothing else is there (a read of a joint velocity or a detection fails, naming what the harness gives). The
  writer always reads it, and so does a controller on the harness's inputs (``ControllerSpec.harness_inputs``).
- ``PrivilegedView`` is a controller's that reads the simulator beyond that (the scripted experts' object detector,
  a camera policy's joint velocities): the task's observation wrapper over ManiSkill's raw layout, the robot's
  joints read from the simulator. Its rows are a privileged upper bound, and the tables say so.
"""

from __future__ import annotations

from typing import Any, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.controllers.harness_proprio import HARNESS_PROPRIO_NAMES, rpy_to_quat

CAMERAS = ("base_camera", "hand_camera")  # the order of their channels in the harness's ``rgb``
ARM_JOINTS = 7  # the Panda's arm joints before its two fingers in ``agent/qpos``


class HarnessObservation(dict):
    """A layout the harness's inputs fill: reading an entry they do not give raises, naming what they give."""

    keeps_kind = True  # ``obs_trees`` copies keep it a HarnessObservation

    def __missing__(self, key: str) -> Any:
        raise KeyError(f"{key!r} is not in the benchmark's policy-side view: MIKASA's harness gives a policy its two "
                       f"cameras, the 7-D proprioception {list(HARNESS_PROPRIO_NAMES)} and the instruction; "
                       f"it has {sorted(self)}")


def _cameras(rgb: np.ndarray) -> dict[str, Any]:
    if rgb.shape[-1] != 3 * len(CAMERAS):
        raise ValueError(f"the harness's rgb has {rgb.shape[-1]} channels; expected {3 * len(CAMERAS)} "
                         f"({' then '.join(CAMERAS)})")
    return HarnessObservation({camera: HarnessObservation(rgb=rgb[..., 3 * i:3 * i + 3])
                               for i, camera in enumerate(CAMERAS)})


def policy_view(obs: Mapping[str, Any]) -> dict[str, Any]:
    """The task's layout (batch of one, numpy) from the harness's ``rgb`` and ``proprio`` alone."""
    from sb3_memret.common.obs_trees import to_numpy

    rgb, proprio = to_numpy(obs["rgb"]), to_numpy(obs["proprio"]).astype(np.float64).reshape(-1, 7)
    tcp_pose = np.concatenate([proprio[:, :3], rpy_to_quat(proprio[:, 3:6])], axis=1).astype(np.float32)
    fingers = np.repeat(proprio[:, 6:7] / 2, 2, axis=1)
    qpos = np.concatenate([np.full((len(proprio), ARM_JOINTS), np.nan), fingers], axis=1).astype(np.float32)
    return HarnessObservation(agent=HarnessObservation(qpos=qpos), extra=HarnessObservation(tcp_pose=tcp_pose),
                              sensor_data=_cameras(rgb))


def raw_observation(env: gym.Env, obs: Mapping[str, Any]) -> dict[str, Any]:
    """ManiSkill's raw observation layout, from the harness's images and the robot's joints and hand pose read from
    the simulator (a privileged controller's)."""
    agent = env.unwrapped.agent
    return {
        "agent": {"qpos": agent.robot.get_qpos(), "qvel": agent.robot.get_qvel()},
        "extra": {"tcp_pose": agent.tcp.pose.raw_pose},
        "sensor_data": dict(_cameras(np.asarray(obs["rgb"]))),
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


class PrivilegedView:
    """``observation(obs)``: a privileged controller's observation (numpy, batch of one) for a harness observation:
    the task's observation wrapper over the raw layout, which reads the simulator."""

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


__all__ = ["CAMERAS", "HarnessObservation", "PrivilegedView", "policy_view", "raw_observation"]
