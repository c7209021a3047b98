"""MIKASA's harness proprioception: the hand's position, its roll-pitch-yaw and the gripper's opening (7 numbers).

The harness hands a policy ``proprio``: the TCP's xyz, its orientation as roll, pitch and yaw (from the wxyz
quaternion, the z-y-x convention) and the two finger joints' positions summed. A learned controller trained with
``state: harness`` reads exactly these seven: derived from its demonstrations' TCP pose and finger joints by
``harness_proprio`` (the harness's own formula), and given by the harness at the benchmark, so that what it learned
from is what the protocol gives a policy. ``tcp_pose_from_proprio`` goes the other way, for the policy-side view
that the writers read (``sb3_memret.benchmark.view``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

HARNESS_PROPRIO_NAMES = ("ee_x", "ee_y", "ee_z", "ee_roll", "ee_pitch", "ee_yaw", "gripper")
TCP_NAMES = ("tcp_x", "tcp_y", "tcp_z", "tcp_qw", "tcp_qx", "tcp_qy", "tcp_qz")
FINGER_NAMES = ("qpos_7", "qpos_8")  # the Panda's two finger joints, after its seven arm joints
SOURCE_NAMES = TCP_NAMES + FINGER_NAMES  # what a layout needs to derive the harness's proprio


def quat_to_rpy(quat: np.ndarray) -> np.ndarray:
    """(..., 4) wxyz quaternions -> (..., 3) roll, pitch, yaw (z-y-x), normalised first as the harness does."""
    q = np.asarray(quat, dtype=np.float64)
    q = q / np.clip(np.linalg.norm(q, axis=-1, keepdims=True), 1e-8, None)
    w, x, y, z = np.moveaxis(q, -1, 0)
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def rpy_to_quat(rpy: np.ndarray) -> np.ndarray:
    """(..., 3) roll, pitch, yaw (z-y-x) -> (..., 4) wxyz quaternions with w >= 0 (``quat_to_rpy``'s inverse)."""
    half = np.asarray(rpy, dtype=np.float64) / 2
    (cr, cp, cy), (sr, sp, sy) = np.moveaxis(np.cos(half), -1, 0), np.moveaxis(np.sin(half), -1, 0)
    quat = np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], axis=-1)
    return np.where(quat[..., :1] < 0, -quat, quat)


def harness_proprio(tcp_pose: np.ndarray, fingers: np.ndarray) -> np.ndarray:
    """(N, 7) TCP poses (xyz, wxyz) and (N, 2) finger joint positions -> (N, 7) float32 harness proprioception."""
    tcp_pose, fingers = np.atleast_2d(tcp_pose), np.atleast_2d(fingers)
    if tcp_pose.shape[-1] != 7 or fingers.shape[-1] != 2 or len(tcp_pose) != len(fingers):
        raise ValueError(f"harness_proprio takes (N, 7) TCP poses and (N, 2) finger positions, got "
                         f"{tcp_pose.shape} and {fingers.shape}")
    return np.concatenate([tcp_pose[:, :3], quat_to_rpy(tcp_pose[:, 3:]), fingers.sum(-1, keepdims=True)],
                          axis=-1).astype(np.float32)


def with_harness_proprio(states: np.ndarray, names: Sequence[str]) -> tuple[np.ndarray, tuple[str, ...]]:
    """(N, S) states laid out as ``names`` -> the states with the seven harness columns appended, and their names;
    a ValueError names the source entries the layout lacks."""
    missing = [name for name in SOURCE_NAMES if name not in names]
    if missing:
        raise ValueError(f"a state layout without {missing} cannot give the harness's proprioception "
                         f"{list(HARNESS_PROPRIO_NAMES)}; it has {list(names)}")
    index = [list(names).index(name) for name in SOURCE_NAMES]
    source = np.asarray(states)[:, index]
    derived = harness_proprio(source[:, :7], source[:, 7:])
    return np.concatenate([np.asarray(states, dtype=np.float32), derived], axis=1), (*names, *HARNESS_PROPRIO_NAMES)


def reads_harness_proprio(state_names: Sequence[str]) -> bool:
    """Whether a policy reading ``state_names`` reads the harness's proprioception (any of its seven entries)."""
    return any(name in HARNESS_PROPRIO_NAMES for name in state_names)


__all__ = ["FINGER_NAMES", "HARNESS_PROPRIO_NAMES", "SOURCE_NAMES", "TCP_NAMES", "harness_proprio", "quat_to_rpy",
           "reads_harness_proprio", "rpy_to_quat", "with_harness_proprio"]
