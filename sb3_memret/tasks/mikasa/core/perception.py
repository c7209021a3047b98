"""What a camera sees of MIKASA-Robo-VLA's RememberColor tasks, and what a frozen controller may read.

``read_cue_colour`` reads the cue from pixels alone; ``ControllerObservation`` strips the env's
observation down to what a controller with a camera and a colour detector would see.

Calibration (SAPIEN 3.0.3 rasteriser, lavapipe, the 128x128 ``base_camera``, 40 episodes of
RememberColor9 with segmentation as ground truth): every cube face is flat-shaded, so each colour
shows exactly two shades, its top face and its camera-facing side. A channel of 255 renders as 231
(top) / 148 (side), 128 as 169 / 108, 0 as 4-5 / 0: the cue cube's mean RGB is (203, 3, 3) for
red and (149, 3, 3) for maroon, (3, 203, 203) for cyan and (3, 149, 149) for teal (all nine in
``CUE_MEAN_RGB``). Cube pixels have a min channel <= 9 and a max >= 108; no pixel of the
table, floor or robot (300k sampled, arm moving) has a min channel below 36.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from scipy import ndimage

# MIKASA's RememberColorVLABaseEnv.COLOR_MAPPING, in order: index i is cube ``cube_{i}``.
COLOUR_NAMES: tuple[str, ...] = ("red", "lime", "blue", "yellow", "magenta", "cyan", "maroon", "olive", "teal")
BASE_RGB: tuple[tuple[int, int, int], ...] = (
    (255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (255, 0, 255),
    (0, 255, 255), (128, 0, 0), (255, 128, 0), (0, 128, 128),
)
# How a base channel value renders on the top and on the camera-facing side of a cube (measured).
FACE_LEVELS: dict[str, dict[int, int]] = {"top": {0: 4, 128: 169, 255: 231}, "side": {0: 0, 128: 108, 255: 148}}
# The cue cube's mean RGB per colour at the table centre, seen from the base camera (measured).
CUE_MEAN_RGB: dict[str, tuple[float, float, float]] = {
    "red": (203.3, 3.2, 3.2), "lime": (3.2, 203.3, 3.2), "blue": (3.2, 3.2, 203.3),
    "yellow": (203.3, 203.3, 3.2), "magenta": (203.3, 3.2, 203.3), "cyan": (3.2, 203.3, 203.3),
    "maroon": (148.7, 3.2, 3.2), "olive": (203.3, 148.7, 3.2), "teal": (3.2, 148.7, 148.7),
}

CUBE_MAX_MIN_CHANNEL = 20  # a cube pixel's darkest channel is <= 9, the background's >= 36
CUBE_MIN_MAX_CHANNEL = 80  # ... and its brightest >= 108 (rules out near-black pixels)
MIN_BLOB_PIXELS = 4  # the cue cube covers 24 pixels at 128x128; smaller specks are not cubes
CUE_PIXEL = (76.5, 63.5)  # (row, col) of the table centre's cube at 128x128: rows 74-79, cols 62-65
CUE_RADIUS = 4.0  # pixels (at 128x128) the single blob's centre may lie from CUE_PIXEL
MIN_VOTE_SHARE = 0.8  # a blob whose pixels disagree more than this is not read
REFERENCE_SIZE = 128
HIDDEN_Z = 10.0  # MIKASA parks hidden cubes at z = 1000 m; anything above this is out of sight


def _palette(n_colours: int) -> tuple[np.ndarray, np.ndarray]:
    """The rendered face shades (2n, 3) of the first ``n_colours`` colours and their colour index."""
    shades = [[FACE_LEVELS[face][c] for c in BASE_RGB[i]] for i in range(n_colours) for face in ("top", "side")]
    return np.asarray(shades, dtype=np.float32), np.repeat(np.arange(n_colours), 2)


def cube_mask(rgb: np.ndarray) -> np.ndarray:
    """Pixels of a saturated primary colour: cubes, never the wooden table, the floor or the robot."""
    rgb = np.asarray(rgb)
    return (rgb.min(axis=-1) <= CUBE_MAX_MIN_CHANNEL) & (rgb.max(axis=-1) >= CUBE_MIN_MAX_CHANNEL)


def cue_blob(rgb: np.ndarray) -> np.ndarray | None:
    """The mask of the one coloured object at the table centre, or None when none or several are in view."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"expected one (H, W, 3) frame, got shape {rgb.shape}")
    labels, n_blobs = ndimage.label(cube_mask(rgb), structure=np.ones((3, 3)))
    sizes = np.bincount(labels.ravel(), minlength=n_blobs + 1)[1:]
    scale = np.array(rgb.shape[:2]) / REFERENCE_SIZE
    blobs = [i + 1 for i, s in enumerate(sizes) if s >= MIN_BLOB_PIXELS * scale.prod()]
    if len(blobs) != 1:
        return None
    blob = labels == blobs[0]
    centre = np.argwhere(blob).mean(axis=0) / scale
    return blob if np.hypot(*(centre - CUE_PIXEL)) <= CUE_RADIUS else None


def read_cue_colour(rgb: np.ndarray, n_colours: int) -> str | None:
    """The colour of the one cube at the table centre, or None when no cube or several are in view.

    Reads one base-camera frame (H, W, 3) uint8 only: the cue phase is the only phase with exactly
    one cube in sight and it stands at the table centre. Each pixel of that cube votes for the
    nearest rendered face shade among the first ``n_colours`` colours (shade, not hue, tells red
    from maroon and cyan from teal).
    """
    if not 1 <= n_colours <= len(COLOUR_NAMES):
        raise ValueError(f"n_colours must be in 1..{len(COLOUR_NAMES)}, got {n_colours}")
    blob = cue_blob(rgb)
    if blob is None:
        return None
    shades, owner = _palette(n_colours)
    pixels = np.asarray(rgb)[blob].astype(np.float32)
    votes = np.bincount(owner[np.argmin(((pixels[:, None] - shades[None]) ** 2).sum(-1), axis=1)], minlength=n_colours)
    best = int(votes.argmax())
    return COLOUR_NAMES[best] if votes[best] >= MIN_VOTE_SHARE * votes.sum() else None


class DetectorObservation(gym.ObservationWrapper):
    """A MIKASA observation cut to what a frozen controller with an object detector may see.

    A controller gets its joints (``agent/qpos``, ``qvel``), its hand (``extra/tcp_pose``), the
    cameras' ``rgb``, and every candidate object's position by index (``extra/{key}_positions``,
    (B, n, 3)) and whether it is in sight (``extra/{key}_visible``, (B, n)); hidden objects (parked
    at z = 1000 by MIKASA) read as invisible and at zero. Everything else is dropped (``oracle_info``,
    ``task_cue``, the ``goal_{i}_pose`` keys of state modes): the cue's answer must reach a
    controller only through its prompt. The env's ``info`` is passed on untouched (metrics only).
    ``actors(base_env)`` lists the candidate objects in index order.
    """

    def __init__(self, env: gym.Env, actors: Callable[[Any], Sequence[Any]], key: str):
        super().__init__(env)
        self._actors, self.key = actors, key
        self.n_objects = len(actors(env.unwrapped))
        batch = int(getattr(env.unwrapped, "num_envs", 1))
        space = env.observation_space
        self.observation_space = spaces.Dict({
            "agent": spaces.Dict({k: space["agent"][k] for k in ("qpos", "qvel")}),
            "extra": spaces.Dict({
                "tcp_pose": space["extra"]["tcp_pose"],
                f"{key}_positions": spaces.Box(-np.inf, np.inf, (batch, self.n_objects, 3), np.float32),
                f"{key}_visible": spaces.Box(0, 1, (batch, self.n_objects), np.bool_),
            }),
            "sensor_data": spaces.Dict({
                cam: spaces.Dict({"rgb": data["rgb"]})
                for cam, data in space.spaces.get("sensor_data", spaces.Dict()).items() if "rgb" in data
            }),
        })

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        """Whitelist the controller's keys and add the detections."""
        actors = self._actors(self.env.unwrapped)
        positions = stack_positions([actor.pose.p for actor in actors], like=obs["extra"]["tcp_pose"])
        visible = positions[..., 2] < HIDDEN_Z
        positions = positions * visible[..., None]
        return {
            "agent": {"qpos": obs["agent"]["qpos"], "qvel": obs["agent"]["qvel"]},
            "extra": {"tcp_pose": obs["extra"]["tcp_pose"], f"{self.key}_positions": positions,
                      f"{self.key}_visible": visible},
            "sensor_data": {
                cam: {"rgb": data["rgb"]} for cam, data in obs.get("sensor_data", {}).items() if "rgb" in data
            },
        }


def _cubes(base: Any) -> list[Any]:
    """MIKASA's candidate cubes by colour index (``base.cubes`` is keyed 0..n-1)."""
    return [base.cubes[i] for i in range(len(base.cubes))]


class ControllerObservation(DetectorObservation):
    """A RememberColor observation cut to a controller's view: ``extra/cube_positions`` (B, n_colours, 3)
    and ``extra/cube_visible`` (B, n_colours) by colour index, as a colour detector would report them.
    Note that the cue cube itself is in sight during the cue phase, as it is to the camera."""

    def __init__(self, env: gym.Env):
        super().__init__(env, _cubes, "cube")
        self.n_colours = self.n_objects


def stack_positions(items: list[Any], like: Any) -> Any:
    """Stack n (B, 3) actor positions to (B, n, 3) in the array type of ``like`` (torch or numpy): what every
    family's controller view reads its objects' positions with."""
    if hasattr(like, "detach"):
        import torch

        return torch.stack([p.to(like.device) for p in items], dim=1).clone()
    return np.stack([p.detach().cpu().numpy() if hasattr(p, "detach") else np.asarray(p) for p in items], axis=1)


__all__ = ["COLOUR_NAMES", "CUE_MEAN_RGB", "ControllerObservation", "DetectorObservation", "cue_blob", "cube_mask",
           "read_cue_colour", "stack_positions"]
