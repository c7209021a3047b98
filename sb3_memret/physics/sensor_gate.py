"""Render a ManiSkill env's cameras only for the observations someone reads.

ManiSkill renders every camera into every observation of an ``rgb`` env. A controller reads images only at its
decisions, and a writer only while something can be seen (``Task.perception_window``); physics never reads the
renderer, so the other renders are pure cost. ``SensorGate`` is installed once on a base env (``of``): while it is
closed, an observation carries the images last rendered; open with ``cameras`` named, it renders those alone (the
writer's camera on a step only the writer reads) and the others carry their last images. Each picture it takes
draws only the bodies its camera can see (``frustum_cull``).
"""

from __future__ import annotations

from contextlib import AbstractContextManager, contextmanager
from typing import Any, Callable, Iterator

import gymnasium as gym

from sb3_memret.physics.frustum_cull import FrustumCull


class SensorGate:
    """Renders a ManiSkill env's cameras only while ``open``: a closed gate's observations carry the images last
    rendered. Open, it renders every camera, or with ``cameras`` set only those (by sensor name), the rest carrying
    their last images. Installed once per base env (``of``), on ManiSkill's one path to the cameras in an
    observation."""

    def __init__(self, base: Any):
        self.open = True
        self.cameras: frozenset[str] | None = None  # while open: the cameras rendered (None: every one)
        self._base = base
        self._render = base._get_obs_sensor_data
        self._last: dict[str, dict[str, Any]] | None = None
        base._get_obs_sensor_data = self._sensor_data
        FrustumCull(base).install()  # and each camera draws only what it can see

    @classmethod
    def of(cls, env: gym.Env) -> "SensorGate":
        """The gate of ``env``'s base env, installed on first use."""
        base = env.unwrapped
        gate = vars(base).get("_sb3_memret_sensor_gate")
        if gate is None:
            gate = base._sb3_memret_sensor_gate = cls(base)
        return gate

    @contextmanager
    def closed(self) -> Iterator[None]:
        """Within, observations carry the images last rendered (for steps whose images nobody reads)."""
        was, self.open = self.open, False
        try:
            yield
        finally:
            self.open = was

    def _sensor_data(self, apply_texture_transforms: bool = True) -> dict[str, dict[str, Any]]:
        if self._last is None or (self.open and self.cameras is None):
            self._last = self._render(apply_texture_transforms)
        elif self.open:
            fresh = self._render_only(self.cameras, apply_texture_transforms)
            self._last = {name: fresh.get(name, data) for name, data in self._last.items()}
        return {name: dict(data) for name, data in self._last.items()}  # wrappers may edit what they get

    def _render_only(self, cameras: frozenset[str], apply_texture_transforms: bool) -> dict[str, dict[str, Any]]:
        """Render ``cameras`` alone: ManiSkill captures the env's sensors and reads the scene's, so both lists are
        narrowed for the call."""
        env, scene = self._base, self._base.scene
        unknown = sorted(cameras - set(scene.sensors))
        if unknown:
            raise ValueError(f"no camera {unknown} to render; the env's cameras are {sorted(scene.sensors)}")
        sensors, captured = scene.sensors, env._sensors
        scene.sensors = {name: sensor for name, sensor in sensors.items() if name in cameras}
        env._sensors = {name: sensor for name, sensor in captured.items() if name in cameras}
        try:
            return self._render(apply_texture_transforms)
        finally:
            scene.sensors, env._sensors = sensors, captured


def sensors_pause(env: gym.Env) -> Callable[[], AbstractContextManager[None]] | None:
    """What pauses ``env``'s cameras for a step whose observation nobody reads: the env's own ``sensors_paused``
    (the drawer's, which leaves the images out), else for any ManiSkill env its ``SensorGate``; None for others."""
    base = env.unwrapped
    own = getattr(base, "sensors_paused", None)
    if own is not None:
        return own
    return SensorGate.of(env).closed if hasattr(base, "_get_obs_sensor_data") else None


__all__ = ["SensorGate", "sensors_pause"]
