"""What a learned controller may see, as flat features: the one layout demonstrations, finetuning and
every learned controller share.

``observation.state`` (19) is the 8-D end-effector state, the three drawer openings and the
8-D cube detection (visible flag, position, wxyz quaternion; all zeros until the cube's drawer
is open, as a camera would see it). Nothing in it names the cube's layer before its drawer
opens, so a policy trained on it must read the layer from its prompt. The two cameras use the
feature names lerobot's π0.5 LIBERO finetuning expects.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from sb3_memret.controllers.base import RENDER_HINT, Obs, as_numpy

if TYPE_CHECKING:
    import torch

STATE_KEY, ACTION_KEY, TASK_KEY = "observation.state", "action", "task"
# decision-frame datasets: each frame's labels for its next chunk_len control steps, and the steps past the episode
ACTION_CHUNK_KEY, CHUNK_PAD_KEY = "action_chunk", "action_chunk_is_pad"
# lerobot's LIBERO feature names for the two cameras, mapped to the task's cameras.
IMAGE_KEYS: Mapping[str, str] = {"observation.images.image": "base_camera",
                                 "observation.images.wrist_image": "hand_camera"}
IMAGE_SHAPE = (224, 224, 3)
STATE_PARTS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("agent", "eef_state", ("tcp_x", "tcp_y", "tcp_z", "tcp_rx", "tcp_ry", "tcp_rz", "finger_left", "finger_right")),
    ("extra", "drawer_opening", ("opening_1", "opening_2", "opening_3")),
    ("extra", "target_detection", ("target_visible", "target_x", "target_y", "target_z", "target_qw", "target_qx", "target_qy",
                                 "target_qz")),
)
STATE_NAMES: tuple[str, ...] = tuple(name for _, _, names in STATE_PARTS for name in names)
STATE_DIM = len(STATE_NAMES)
# what a real robot reads of itself: the end-effector state; a camera-reading controller gets only these
PROPRIO_NAMES: tuple[str, ...] = STATE_PARTS[0][2]
ACTION_NAMES = ("dx", "dy", "dz", "drx", "dry", "drz", "gripper")
ACTION_DIM = len(ACTION_NAMES)


def observation_state(obs: Obs) -> np.ndarray:
    """(B, 19) float32 controller state from a batched DrawerCubeTakeOut-v1 observation."""
    parts = []
    for group, key, names in STATE_PARTS:
        try:
            value = as_numpy(obs[group][key])
        except KeyError:
            raise ValueError(f"the observation has no {group}/{key}; a learned controller reads the state_dict or "
                             "rgb observation of DrawerCubeTakeOut-v1") from None
        value = value.reshape(-1, value.shape[-1]) if value.ndim else value.reshape(1, 1)
        if value.shape[-1] != len(names):
            raise ValueError(f"{group}/{key} has {value.shape[-1]} values per env, expected {len(names)}")
        parts.append(value.astype(np.float32))
    return np.concatenate(parts, axis=1)


def camera_images(obs: Obs) -> dict[str, np.ndarray]:
    """The two camera images (B, 224, 224, 3) uint8 under their dataset feature names."""
    images = {}
    for feature, camera in IMAGE_KEYS.items():
        rgb = obs.get("sensor_data", {}).get(camera, {}).get("rgb")
        if rgb is None:
            raise ValueError(f"the observation has no {camera} image (sensor_data/{camera}/rgb), read as {feature}; "
                             + RENDER_HINT)
        image = as_numpy(rgb)
        if image.shape[1:] != IMAGE_SHAPE or image.dtype != np.uint8:
            raise ValueError(f"{camera} images are {image.dtype}{image.shape[1:]}; expected uint8{IMAGE_SHAPE}")
        images[feature] = image
    return images


def resize_image_tensor(images: torch.Tensor, size: int) -> torch.Tensor:
    """(B, 3, H, W) uint8 -> (B, 3, size, size) float holding uint8 values: area-averaged and rounded as the
    demonstrations were stored, on whatever device ``images`` is (a GPU controller resizes on its GPU)."""
    from torch.nn import functional as F

    x = images.float()
    if tuple(x.shape[-2:]) == (size, size):
        return x
    return F.interpolate(x, size=(size, size), mode="area").round().clamp(0, 255)


def resize_images(images: np.ndarray, size: int) -> np.ndarray:
    """(B, H, W, 3) uint8 -> (B, size, size, 3) uint8 by area averaging (unchanged when already that size)."""
    if images.shape[1:3] == (size, size):
        return images
    import torch

    x = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2)
    return resize_image_tensor(x, size).to(torch.uint8).permute(0, 2, 3, 1).numpy()


def dataset_features(with_images: bool, image_size: int = IMAGE_SHAPE[0],
                     chunk_len: int | None = None) -> dict[str, dict[str, Any]]:
    """The LeRobotDataset feature spec of a demonstration frame (``task`` is added by lerobot): with
    ``chunk_len``, a decision frame carrying its chunk of labels (``action_chunk``, ``action_chunk_is_pad``)."""
    features: dict[str, dict[str, Any]] = {
        STATE_KEY: {"dtype": "float32", "shape": (STATE_DIM,), "names": list(STATE_NAMES)},
        ACTION_KEY: {"dtype": "float32", "shape": (ACTION_DIM,), "names": list(ACTION_NAMES)},
    }
    if chunk_len is not None:
        features.update(chunk_features(chunk_len))
    if with_images:
        for feature in IMAGE_KEYS:
            features[feature] = {"dtype": "image", "shape": (image_size, image_size, 3),
                                 "names": ["height", "width", "channel"]}
    return features


def chunk_features(chunk_len: int) -> dict[str, dict[str, Any]]:
    """The features of a decision frame's label chunk."""
    return {ACTION_CHUNK_KEY: {"dtype": "float32", "shape": (chunk_len, ACTION_DIM), "names": None},
            CHUNK_PAD_KEY: {"dtype": "bool", "shape": (chunk_len,), "names": None}}


__all__ = ["ACTION_CHUNK_KEY", "ACTION_DIM", "ACTION_KEY", "CHUNK_PAD_KEY", "IMAGE_KEYS", "IMAGE_SHAPE", "PROPRIO_NAMES",
           "STATE_DIM", "STATE_KEY", "STATE_NAMES", "TASK_KEY", "camera_images", "chunk_features", "dataset_features",
           "observation_state", "resize_image_tensor", "resize_images"]
