"""Serve any frozen controller over openpi's websocket protocol, with openpi's own server (``openpi-server``).

Requests carry the pi05_libero keys (``observation/image``, ``observation/wrist_image``,
``observation/state`` (8), ``prompt``) and, from the project's client, ``observation/drawer_opening``
(3) and ``observation/cube_detection`` (8) so that state-only controllers can act. openpi's
protocol has no episodes, so the project's client also sends ``sb3_memret/client`` (one id per
client), ``sb3_memret/env`` (the env's slot in its batch) and ``sb3_memret/episode`` (a new
number whenever that slot starts an episode). A controller that keeps per-episode state (the
scripted expert's plan) gets one instance per (client, slot), reset when the slot's episode
changes; a stateless one is shared. A request without those keys (a plain openpi client) is
slot 0 of one continuing episode. The reply is ``{"actions": (chunk_len, action_dim)}``; errors
reach the client as openpi's traceback frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_memret.controllers import make_controller
from sb3_memret.controllers.base import FrozenController
from sb3_memret.controllers.openpi import CAMERAS, CLIENT_KEY, ENV_KEY, EPISODE_KEY, EXTRA_STATE

STATE_KEY, PROMPT_KEY = "observation/state", "prompt"


class ControllerPolicy:
    """An openpi policy (``infer(obs) -> {"actions": ...}``) backed by a controller spec such as ``learned``."""

    def __init__(self, controller: str):
        self.controller_spec = controller
        self._first = make_controller(controller)  # a bad spec fails here, before serving
        self.spec = self._first.spec
        self._slots: dict[tuple[str, int], tuple[FrozenController, Any]] = {}

    @property
    def metadata(self) -> dict[str, Any]:
        """What the server sends on connect: enough for the client to match the controller exactly."""
        template = self.spec.prompt_template
        return {"server": "sb3-memret", "controller": self.controller_spec, "action_horizon": self.spec.chunk_len,
                "action_dim": self.spec.action_dim, "action_convention": self.spec.action_convention,
                "needs_images": self.spec.needs_images,
                "prompt_template": {"instructions": list(template.instructions),
                                    "fact_templates": list(template.fact_templates)}}

    def infer(self, request: dict[str, Any]) -> dict[str, np.ndarray]:
        obs = self._observation(request)
        controller = self._controller_for(request)
        return {"actions": controller.act(obs, [request[PROMPT_KEY]])[0]}

    def _controller_for(self, request: dict[str, Any]) -> FrozenController:
        """The slot's controller, reset when its episode changed (every call for a stateless one)."""
        slot = (str(request.get(CLIENT_KEY, "")), int(request.get(ENV_KEY, 0)))
        episode = request.get(EPISODE_KEY)
        if not self._first.stateful:
            self._first.reset([0])
            return self._first
        controller, current = self._slots.get(slot, (None, None))
        if controller is None:
            controller = self._first if not self._slots else make_controller(self.controller_spec)
        if slot not in self._slots or episode != current:
            controller.reset([int(episode or 0)])
        self._slots[slot] = (controller, episode)
        return controller

    def _observation(self, request: dict[str, Any]) -> dict[str, Any]:
        """The request as a batch-of-one DrawerCubeTakeOut-v1 observation, refusing what the controller lacks."""
        needed = [STATE_KEY, PROMPT_KEY] + ([*CAMERAS] if self.spec.needs_images else [*EXTRA_STATE])
        missing = [key for key in needed if key not in request]
        if missing:
            raise ValueError(f"the request lacks {missing} that controller {self.controller_spec!r} reads; the "
                             "sb3-memret openpi client (--controller openpi://HOST:PORT) sends them")
        obs: dict[str, Any] = {"agent": {"eef_state": np.asarray(request[STATE_KEY], np.float32)[None]},
                               "extra": {part: np.asarray(request[key], np.float32)[None]
                                         for key, part in EXTRA_STATE.items() if key in request},
                               "sensor_data": {camera: {"rgb": np.asarray(request[key], np.uint8)[None]}
                                               for key, camera in CAMERAS.items() if key in request}}
        return obs


def serve(policy: ControllerPolicy, host: str = "0.0.0.0", port: int = 8000) -> None:
    """Serve ``policy`` on ws://host:port with openpi's server until interrupted."""
    from openpi_server import WebsocketPolicyServer

    WebsocketPolicyServer(policy, host=host, port=port, metadata=policy.metadata).serve_forever()


__all__ = ["ControllerPolicy", "serve"]
