"""What the drawer's simulator knows and its writer and reward read (``DrawerCubeState``), and which drawer holds a
point; kept apart from the ManiSkill env so that the writer, the task and the command line load without it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class DrawerCubeState:
    """Privileged simulator state for the memory writer and the reward (batched, numpy).

    Only the writer and the reward may read this; controllers see observations only.
    """

    target_pos: np.ndarray  # (B, 3) the object the instruction names
    target_quat: np.ndarray  # (B, 4) wxyz
    target_layer: np.ndarray  # (B,) layer the episode placed the target in (1 = top)
    object_names: np.ndarray  # (B, M) str: the task's objects, in its order
    object_layer: np.ndarray  # (B, M) layer each object was placed in, 0 if this episode leaves it out
    object_pos: np.ndarray  # (B, M, 3)
    target_index: np.ndarray  # (B,) the target's index into the objects
    layer_boxes: np.ndarray  # (B, 3, 2, 3) per layer: (low, high) corners of the interior
    drawer_qpos: np.ndarray  # (B, 3) opening of drawers 1..3 in metres
    grasped: np.ndarray  # (B,) bool: both fingers press on the target
    eef_pos: np.ndarray  # (B, 3) tool centre point
    eef_quat: np.ndarray  # (B, 4) wxyz

    def select(self, index: int) -> "DrawerCubeState":
        """Env ``index`` alone, as a batch of one."""
        return DrawerCubeState(**{name: value[index:index + 1] for name, value in vars(self).items()})

    @property
    def target_in_layer(self) -> np.ndarray:
        """(B,) the layer whose interior box holds the target's centre, 0 if none."""
        return layer_containing(self.target_pos, self.layer_boxes)

    def target_name(self, index: int = 0) -> str:
        return str(self.object_names[index, self.target_index[index]])

    def placed(self, index: int = 0) -> dict[str, int]:
        """Env ``index``'s objects in this episode by name, with the layer each was placed in."""
        return {str(name): int(layer) for name, layer in zip(self.object_names[index], self.object_layer[index])
                if layer > 0}


def layer_containing(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Index (1-based) of the box containing each point, 0 where none does.

    ``points`` is (B, 3) and ``boxes`` (B, L, 2, 3); boxes of one env never overlap.
    """
    inside = np.all((points[:, None] >= boxes[:, :, 0]) & (points[:, None] <= boxes[:, :, 1]), axis=-1)
    return np.where(inside.any(axis=1), inside.argmax(axis=1) + 1, 0)


__all__ = ["DrawerCubeState", "layer_containing"]
