"""What BatteriesChecker's expert sees: joints, hand, cameras, and an object detector's batteries, tray slots, socket
and button (a privileged view: the rows it plays are an upper bound). The lamp is not in it."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.tasks.mikasa.core.perception import DetectorObservation, stack_positions


def active_batteries(base: Any) -> list[Any]:
    """MIKASA's batteries in play, in its index order (battery i stands in tray slot i + 1)."""
    return list(base.batteries[: int(base.ACTIVE_BATTERY_COUNT)])


class BatteryObservation(DetectorObservation):
    """A BatteriesChecker observation cut to a controller's view: the joints, the hand, the cameras, the batteries in
    play (``extra/battery_positions`` (B, n, 3), their centres, and ``extra/battery_visible``), their tray slots
    (``extra/slot_positions`` (B, n, 3): where each battery stands at home), the socket's seat
    (``extra/socket_position`` (B, 3)) and the button's cap top (``extra/button_position`` (B, 3)). Which batteries
    work, the lamp and MIKASA's check counters are not among them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, active_batteries, "battery")
        batch, n = int(getattr(env.unwrapped, "num_envs", 1)), self.n_objects
        extra = self.observation_space["extra"]
        extra["slot_positions"] = spaces.Box(-np.inf, np.inf, (batch, n, 3), np.float32)
        extra["socket_position"] = spaces.Box(-np.inf, np.inf, (batch, 3), np.float32)
        extra["button_position"] = spaces.Box(-np.inf, np.inf, (batch, 3), np.float32)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        base, like = self.env.unwrapped, out["extra"]["tcp_pose"]
        slots = base.tray_slot_positions[:, : self.n_objects]
        cap = torch_cat_xy_z(base.button_xy, base.button_top_z)
        out["extra"]["slot_positions"] = stack_positions([slots[:, i] for i in range(self.n_objects)], like=like)
        out["extra"]["socket_position"] = stack_positions([base.socket_slot_pos], like=like)[:, 0]
        out["extra"]["button_position"] = stack_positions([cap], like=like)[:, 0]
        return out


def torch_cat_xy_z(xy: Any, z: Any) -> Any:
    """(B, 3) points from (B, 2) xy and (B,) heights (torch tensors, as MIKASA keeps them)."""
    import torch

    return torch.cat([xy, z.reshape(-1, 1)], dim=1)


__all__ = ["BatteryObservation", "active_batteries"]
