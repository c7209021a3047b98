"""The flat frame layout of MIKASA demonstrations (LeRobotDataset features): what a controller may see.

``observation.state``: joints (``qpos``, ``qvel``), the hand (``tcp_pose``: xyz + wxyz) and what the
object detector of ``ControllerObservation`` reports (each candidate's position and whether it is in
sight; zeros while hidden, so the cue's answer never shows in the state after the cue phase). With
cameras, MIKASA's two 128x128 views under lerobot's LIBERO feature names. The 7-D action is
MIKASA's ``pd_ee_delta_pose`` (translation, rotation, gripper).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from sb3_memret.controllers.base import RENDER_HINT, Obs, as_numpy
from sb3_memret.controllers.observation import ACTION_KEY, ACTION_NAMES, IMAGE_KEYS, STATE_KEY

MIKASA_IMAGE_SHAPE = (128, 128, 3)
ARM_JOINTS = 9  # 7 arm joints + 2 fingers
HAND_POSITION = ("tcp_x", "tcp_y", "tcp_z")  # where the hand (the TCP) is, in the frame of the objects' positions


def state_names(objects: Sequence[str], key: str = "cube") -> tuple[str, ...]:
    """The names of the state's entries, for candidates named by ``objects`` (colours or shapes)."""
    arm = [f"qpos_{i}" for i in range(ARM_JOINTS)] + [f"qvel_{i}" for i in range(ARM_JOINTS)]
    hand = [*HAND_POSITION, "tcp_qw", "tcp_qx", "tcp_qy", "tcp_qz"]
    objects = [name.replace(" ", "_") for name in objects]  # "t shape", "red cube": one token each
    seen = [f"{key}_{name}_{axis}" for name in objects for axis in "xyz"] + [f"{key}_{name}_visible" for name in objects]
    return tuple(arm + hand + seen)


def proprio_names() -> tuple[str, ...]:
    """The state entries a robot reads of itself: joints and hand pose (no detector)."""
    return state_names(())


def demo_features(objects: Sequence[str], with_images: bool, key: str = "cube") -> dict[str, dict[str, Any]]:
    """The LeRobotDataset feature spec of one MIKASA demonstration frame (``task`` is added by lerobot)."""
    names = state_names(objects, key)
    features: dict[str, dict[str, Any]] = {
        STATE_KEY: {"dtype": "float32", "shape": (len(names),), "names": list(names)},
        ACTION_KEY: {"dtype": "float32", "shape": (len(ACTION_NAMES),), "names": list(ACTION_NAMES)},
    }
    if with_images:
        for feature in IMAGE_KEYS:
            features[feature] = {"dtype": "image", "shape": MIKASA_IMAGE_SHAPE, "names": ["height", "width", "channel"]}
    return features


def demo_frame(obs: Obs, with_images: bool, key: str = "cube") -> dict[str, np.ndarray]:
    """One frame of a batch-1 ``ControllerObservation`` observation in ``demo_features``' layout."""
    extra = obs["extra"]
    parts = [obs["agent"]["qpos"], obs["agent"]["qvel"], extra["tcp_pose"], extra[f"{key}_positions"],
             extra[f"{key}_visible"]]
    arrays = [as_numpy(p).reshape(1, -1).astype(np.float32) for p in parts]
    frame = {STATE_KEY: np.concatenate(arrays, axis=1)[0]}
    for feature, camera in IMAGE_KEYS.items() if with_images else ():
        rgb = obs.get("sensor_data", {}).get(camera, {}).get("rgb")
        if rgb is None:
            raise ValueError(f"the observation has no {camera} image (sensor_data/{camera}/rgb); " + RENDER_HINT)
        image = as_numpy(rgb)[0]
        if image.shape != MIKASA_IMAGE_SHAPE or image.dtype != np.uint8:
            raise ValueError(f"{camera} images are {image.dtype}{image.shape}; expected uint8{MIKASA_IMAGE_SHAPE}")
        frame[feature] = image
    return frame


def with_state_extra(features: dict[str, dict[str, Any]], name: str) -> dict[str, dict[str, Any]]:
    """``features`` whose state ends with one more detected point, ``{name}_x``, ``{name}_y``, ``{name}_z``
    (a task's detector beyond the candidates: SeqOfColors' button, TakeItBack's cube)."""
    names = list(features[STATE_KEY]["names"]) + [f"{name}_{axis}" for axis in "xyz"]
    return {**features, STATE_KEY: {**features[STATE_KEY], "shape": (len(names),), "names": names}}


def append_state(frame: dict[str, np.ndarray], point: Any) -> dict[str, np.ndarray]:
    """``frame`` whose state ends with ``point`` (a batch-1 (1, 3) detection), as ``with_state_extra`` names it."""
    point = as_numpy(point).reshape(1, -1).astype(np.float32)[0]
    return {**frame, STATE_KEY: np.concatenate([frame[STATE_KEY], point])}


__all__ = ["MIKASA_IMAGE_SHAPE", "append_state", "demo_features", "demo_frame", "proprio_names", "state_names",
           "with_state_extra"]
