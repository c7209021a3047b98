"""The ShellGame controllers' views: joints, hand, cameras and a detector of three identical cups (and the lamp's
colour)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.tasks.mikasa.core.perception import HIDDEN_Z, DetectorObservation, stack_positions
from sb3_memret.tasks.mikasa.shell_game.variants import LAMP_COLOURS


def _mugs(base: Any) -> list[Any]:
    """MIKASA's three mugs (left, center, right as they start)."""
    return [base.mug_left, base.mug_center, base.mug_right]



def _bulbs(base: Any) -> list[Any]:
    """The ColorLamp lamp's coloured bulbs, in ``LAMP_COLOURS`` order (MIKASA parks the dark ones 1000 m up)."""
    return [base.lamp_red, base.lamp_green, base.lamp_blue]



class CupObservation(DetectorObservation):
    """A ShellGame observation cut to a controller's view: joints, hand, cameras, and what a detector of three
    identical cups reports: ``extra/cup_positions`` (B, 3, 3) and ``extra/cup_visible`` (B, 3), the cups in
    sight ordered left to right (by y; hidden ones last, at zero). The detector cannot tell the cups apart, so
    it never says which cup is which: after a shuffle, which cup hides the ball reaches a controller only through
    its prompt."""

    def __init__(self, env: gym.Env):
        super().__init__(env, _mugs, "cup")

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        extra = out["extra"]
        extra["cup_positions"], extra["cup_visible"] = left_to_right(extra["cup_positions"], extra["cup_visible"])
        return out



def left_to_right(positions: Any, visible: Any) -> tuple[Any, Any]:
    """Detections (B, n, 3) and their visibility (B, n) reordered per env by y, the hidden ones last (numpy or
    torch, as given)."""
    if hasattr(positions, "detach"):
        import torch

        order = torch.argsort(positions[..., 1] + 1e6 * (~visible.bool()), dim=1)
        return (torch.gather(positions, 1, order[..., None].expand(-1, -1, positions.shape[-1])),
                torch.gather(visible, 1, order))
    positions, visible = np.asarray(positions), np.asarray(visible)
    order = np.argsort(positions[..., 1] + 1e6 * ~visible.astype(bool), axis=1, kind="stable")
    return np.take_along_axis(positions, order[..., None], axis=1), np.take_along_axis(visible, order, axis=1)



class LampCupObservation(CupObservation):
    """``CupObservation`` plus the lamp, as the camera shows it: ``extra/lamp_visible`` (B, 3), which bulb is lit
    (red, green, blue; none while the lamp is white)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        batch = int(getattr(env.unwrapped, "num_envs", 1))
        self.observation_space["extra"]["lamp_visible"] = spaces.Box(0, 1, (batch, len(LAMP_COLOURS)), np.bool_)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        bulbs = stack_positions([bulb.pose.p for bulb in _bulbs(self.env.unwrapped)], like=obs["extra"]["tcp_pose"])
        out["extra"]["lamp_visible"] = bulbs[..., 2] < HIDDEN_Z
        return out


__all__ = ["CupObservation", "LampCupObservation", "left_to_right"]
