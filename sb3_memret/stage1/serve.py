"""Serve any frozen controller over openpi's websocket protocol, with openpi's own server (``openpi-server``).

Requests carry the pi05_libero keys (``observation/image``, ``observation/wrist_image`` (uint8
224x224x3), ``observation/state`` (the 8-D eef state), ``prompt``) and, from the project's client,
``observation/drawer_opening`` (3) and ``observation/target_detection`` (8) so that state-only
controllers can act. Each request becomes a batch-of-one DrawerCubeTakeOut-v1 observation for
``controller.act``, which still checks the prompt against the controller's template; a key the
controller reads but the request lacks is an error naming it, which reaches the client as openpi's
traceback frame. The reply is ``{"actions": (chunk_len, action_dim) float32}``.

Episodes: openpi's protocol has none, so the project's client also sends ``sb3_memret/client``
(one id per client), ``sb3_memret/env`` (the env's slot in its batch), ``sb3_memret/episode`` (a new
number whenever the client's ``reset`` starts episodes) and ``sb3_memret/seed`` (that slot's
seed). A controller that keeps per-episode state (the scripted expert's plan, π0.5's noise
generator) gets one instance per (client, slot), reset with the slot's seed whenever its episode
number changes; the instances are shallow copies of one built controller, sharing its weights
(``reset`` replaces the per-episode state). A stateless controller is one shared instance. A
request without those keys (a plain openpi client) is slot 0 of one continuing episode.
"""

from __future__ import annotations

import copy
from typing import Any, Mapping

import numpy as np

from sb3_memret.controllers import make_controller
from sb3_memret.controllers.base import FrozenController
from sb3_memret.controllers.observation import IMAGE_SHAPE, STATE_PARTS
from sb3_memret.controllers.openpi import CAMERAS, CLIENT_KEY, ENV_KEY, EPISODE_KEY, EXTRA_STATE, SEED_KEY

STATE_KEY, PROMPT_KEY = "observation/state", "prompt"
SIZES = {key: len(names) for _, key, names in STATE_PARTS}  # eef_state 8, drawer_opening 3, target_detection 8
MAX_SLOTS = 4096  # per-slot controllers kept; the least recently used beyond this are dropped


class _RequestGroup(dict):
    """One group of the rebuilt observation: reading a part the request did not carry names the request key."""

    def __init__(self, parts: dict[str, np.ndarray], request_keys: Mapping[str, str]):
        super().__init__(parts)
        self.request_keys = request_keys  # observation part -> request key

    def __missing__(self, part: str) -> Any:
        key = self.request_keys.get(part, part)
        raise ValueError(f"the request lacks {key!r}, which the served controller reads; the sb3-memret openpi "
                         "client (--controller openpi://HOST:PORT) sends it")


class ControllerPolicy:
    """An openpi policy (``infer(obs) -> {"actions": ...}``) backed by a controller spec such as ``learned``."""

    def __init__(self, controller: str):
        self.controller_spec = controller
        self._template = make_controller(controller)  # a bad spec fails here, before serving
        self.spec = self._template.spec
        self._slots: dict[tuple[str, int], tuple[FrozenController, Any]] = {}  # slot -> (controller, episode)

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
        """One request -> ``{"actions": (chunk_len, action_dim)}`` from its slot's controller."""
        obs = self._observation(request)
        return {"actions": self._controller_for(request).act(obs, [request[PROMPT_KEY]])[0]}

    def _controller_for(self, request: dict[str, Any]) -> FrozenController:
        """The request's slot's controller, reset when the slot's episode changed (every call if stateless)."""
        if not self._template.stateful:
            self._template.reset([0])
            return self._template
        slot = (str(request.get(CLIENT_KEY, "")), int(request.get(ENV_KEY, 0)))
        episode = request.get(EPISODE_KEY)
        held = self._slots.pop(slot, None)
        controller = held[0] if held is not None else copy.copy(self._template)
        if held is None or held[1] != episode:
            controller.reset([int(request.get(SEED_KEY, 0))])
        self._slots[slot] = (controller, episode)  # re-inserted: the dict runs least to most recently used
        if len(self._slots) > MAX_SLOTS:
            del self._slots[next(iter(self._slots))]
        return controller

    def _observation(self, request: dict[str, Any]) -> dict[str, Any]:
        """The request as a batch-of-one DrawerCubeTakeOut-v1 observation, refusing what the controller lacks."""
        needed = [STATE_KEY, PROMPT_KEY] + ([*CAMERAS] if self.spec.needs_images else [])
        missing = [key for key in needed if key not in request]
        if missing:
            raise ValueError(f"the request lacks {missing}, which controller {self.controller_spec!r} reads; the "
                             "sb3-memret openpi client (--controller openpi://HOST:PORT) sends them")
        extra = {part: _array(request, key, (SIZES[part],), np.float32) for key, part in EXTRA_STATE.items()
                 if key in request}
        cameras = {camera: {"rgb": _array(request, key, IMAGE_SHAPE, np.uint8)} for key, camera in CAMERAS.items()
                   if key in request}
        return {"agent": {"eef_state": _array(request, STATE_KEY, (SIZES["eef_state"],), np.float32)},
                "extra": _RequestGroup(extra, {part: key for key, part in EXTRA_STATE.items()}),
                "sensor_data": _RequestGroup(cameras, {camera: key for key, camera in CAMERAS.items()})}


def _array(request: dict[str, Any], key: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """``request[key]`` with a batch axis of one, refused unless it has ``shape`` (images: also ``dtype``)."""
    value = np.asarray(request[key])
    if value.shape != shape or (dtype is np.uint8 and value.dtype != np.uint8):
        raise ValueError(f"request key {key!r} is {value.dtype}{value.shape}; expected {np.dtype(dtype)}{shape}")
    return value.astype(dtype)[None]


def serve(policy: ControllerPolicy | str, host: str = "0.0.0.0", port: int = 8000) -> None:
    """Serve a controller (a ``ControllerPolicy`` or a controller spec) on ws://host:port until interrupted."""
    from openpi_server import WebsocketPolicyServer

    policy = ControllerPolicy(policy) if isinstance(policy, str) else policy
    WebsocketPolicyServer(policy, host=host, port=port, metadata=policy.metadata).serve_forever()


__all__ = ["ControllerPolicy", "serve"]
