"""π0.5 behind an openpi policy server (``scripts/serve_policy.py``), as a frozen controller.

The server speaks openpi's websocket protocol: on connect it sends its metadata, then answers
each msgpack-numpy observation with ``{"actions": (H, 7), ...}``, or with a text frame holding
its traceback when inference fails. It serves one observation per request, so ``act`` sends one
request per env. Observations are mapped to the ``pi05_libero`` keys exactly as the task renders
them (no flips, resizes or frame changes): ``observation/image`` is ``base_camera``,
``observation/wrist_image`` is ``hand_camera``, ``observation/state`` is the 8-D ``eef_state``.
Beside them go the drawer openings, the cube detection and the episode keys (client id, env slot,
episode number, seed): a pi05_libero server ignores them, ``sb3-memret serve`` reads them
(``sb3_memret.stage1.serve``). Cameras are sent only when the server's metadata does not say its
controller works without them.

openpi's own client waits forever for a reply; this one bounds every wait (connect, metadata,
each inference), retries a bounded number of times, then raises naming the server and the limit.
With ``SB3_MEMRET_SERVE_API_KEY`` set it sends that key as openpi's client sends its ``api_key``
(``Authorization: Api-Key KEY``), which a server started by ``sb3-memret serve`` with a key requires.
"""

from __future__ import annotations

import contextlib
import os
import time
import uuid
from dataclasses import dataclass
from typing import Any, Callable, Sequence, TypeVar

import numpy as np

try:
    import websockets.exceptions
    import websockets.sync.client
    from openpi_client import msgpack_numpy
except ImportError as err:
    raise ImportError(
        f"OpenPIController needs openpi-client and websockets ({err}); install them with "
        "`pip install --no-deps openpi-client==0.1.2` (it pins numpy<2, which this project does not need) "
        "and `pip install 'sb3-memret[openpi]'`"
    ) from err

from sb3_memret.controllers.base import RENDER_HINT, ControllerSpec, FrozenController, Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate

PI05_LIBERO_ACTION_HORIZON = 10  # openpi's pi05_libero config: Pi0Config(pi05=True, action_horizon=10)
IMAGE_SHAPE = (224, 224, 3)
STATE_DIM = 8
CAMERAS = {"observation/image": "base_camera", "observation/wrist_image": "hand_camera"}
# Sent beside the pi05_libero keys (a pi05_libero server ignores them): what a state-only controller
# served by `sb3-memret serve` reads, and episode boundaries for controllers that keep per-episode state.
EXTRA_STATE = {"observation/drawer_opening": "drawer_opening", "observation/target_detection": "target_detection"}
CLIENT_KEY, ENV_KEY = "sb3_memret/client", "sb3_memret/env"
EPISODE_KEY, SEED_KEY = "sb3_memret/episode", "sb3_memret/seed"
API_KEY_ENV = "SB3_MEMRET_SERVE_API_KEY"  # the key `sb3-memret serve` requires, sent when set
T = TypeVar("T")
CLOSE_TIMEOUT = 0.5  # s; a dropped connection is not worth waiting longer for its closing handshake


class PolicyServerError(RuntimeError):
    """The policy server answered a request with an error instead of actions."""


@dataclass(frozen=True)
class ServerLimits:
    """How long to wait for the server and how often to try before giving up (seconds)."""

    connect_timeout: float = 10.0
    infer_timeout: float = 30.0
    attempts: int = 3
    backoff: float = 0.5

    def __post_init__(self) -> None:
        if self.attempts < 1 or min(self.connect_timeout, self.infer_timeout) <= 0 or self.backoff < 0:
            raise ValueError(f"invalid server limits {self}: need attempts >= 1, timeouts > 0, backoff >= 0")


class PolicyServerClient:
    """One websocket connection to an openpi server; every wait bounded, failures retried then raised."""

    def __init__(self, host: str, port: int, limits: ServerLimits | None = None):
        self.uri = f"ws://[{host}]:{port}" if ":" in host else f"ws://{host}:{port}"  # IPv6 literals in brackets
        self.limits = limits or ServerLimits()
        self._ws: websockets.sync.client.ClientConnection | None = None
        self._closer = contextlib.ExitStack()  # closes the open connection, if any
        self.metadata: dict = {}
        self._retrying(self._connect, "connect")

    def infer(self, request: dict[str, Any]) -> dict[str, Any]:
        """Send one observation, return the server's reply; PolicyServerError if it reports an error."""
        return self._retrying(lambda: self._infer_once(request), "infer")

    def close(self) -> None:
        self._closer.close()
        self._ws = None

    def _connect(self) -> None:
        self.close()
        with contextlib.ExitStack() as stack:
            # No keepalive pings: openpi's server cannot answer them during inference, and every wait
            # here is bounded anyway.
            try:
                ws = stack.enter_context(websockets.sync.client.connect(
                    self.uri, open_timeout=self.limits.connect_timeout, close_timeout=CLOSE_TIMEOUT,
                    ping_interval=None, compression=None, max_size=None, additional_headers=api_key_header(),
                ))
            except websockets.exceptions.InvalidStatus as err:
                if err.response.status_code not in (401, 403):
                    raise
                refusal = err.response.body.decode(errors="replace").strip()  # retrying cannot help
                raise PolicyServerError(f"openpi server at {self.uri} refused the connection (HTTP "
                                        f"{err.response.status_code}: {refusal}); set {API_KEY_ENV} to the API key "
                                        "it serves with") from err
            self.metadata = msgpack_numpy.unpackb(ws.recv(timeout=self.limits.connect_timeout))
            self._ws, self._closer = ws, stack.pop_all()

    def _infer_once(self, request: dict[str, Any]) -> dict[str, Any]:
        if self._ws is None:
            self._connect()
        self._ws.send(msgpack_numpy.packb(request))
        reply = self._ws.recv(timeout=self.limits.infer_timeout)
        if isinstance(reply, str):  # openpi sends the traceback as text, then closes the connection
            self.close()
            raise PolicyServerError(f"openpi server at {self.uri} failed on the request:\n{reply}")
        return msgpack_numpy.unpackb(reply)

    def _retrying(self, call: Callable[[], T], what: str) -> T:
        """Run ``call`` up to ``attempts`` times; a timeout or a lost connection drops the socket first."""
        limit = self.limits.connect_timeout if what == "connect" else self.limits.infer_timeout
        failures = []
        for attempt in range(self.limits.attempts):
            if attempt:
                time.sleep(self.limits.backoff * attempt)
            try:
                return call()
            except (TimeoutError, OSError, websockets.exceptions.WebSocketException) as err:
                self.close()  # a late reply must never answer the next request
                failures.append(err)
        timed_out = all(isinstance(e, TimeoutError) for e in failures)
        error = TimeoutError if timed_out else ConnectionError
        detail = f"no reply within {limit:g} s" if timed_out else f"last error: {failures[-1]!r}"
        raise error(
            f"openpi policy server at {self.uri}: {what} failed {len(failures)} times ({detail}); "
            "is `scripts/serve_policy.py` running there and reachable?"
        ) from failures[-1]


class OpenPIController(FrozenController):
    """π0.5 (``pi05_libero`` inputs and outputs) served by openpi, queried once per env and decision.

    ``chunk_len`` defaults to the ``action_horizon`` the server's metadata publishes, else to
    pi05_libero's 10; every reply must match it exactly. A server started by ``sb3-memret serve``
    also publishes whether its controller reads images, its action size and convention and its
    prompt template, which this client then follows (prompts are still checked here); another server's controller
    takes ``prompt_template``, else ``task_template`` (the prompts of the task it was finetuned on).
    """

    def __init__(
        self,
        host: str,
        port: int,
        chunk_len: int | None = None,
        limits: ServerLimits | None = None,
        prompt_template: PromptTemplate | None = None,
        task_template: PromptTemplate | None = None,
    ):
        if chunk_len is not None and chunk_len < 1:
            raise ValueError(f"chunk_len must be >= 1, got {chunk_len}")
        self.client = PolicyServerClient(host, port, limits)
        served = self.client.metadata
        served_horizon = int(served.get("action_horizon", PI05_LIBERO_ACTION_HORIZON))
        if prompt_template is None and "prompt_template" in served:
            template = served["prompt_template"]
            fields = template.get("fields", task_template.fields if task_template is not None else ())
            prompt_template = PromptTemplate(tuple(template["instructions"]), tuple(template["fact_templates"]),
                                             tuple(tuple(pair) for pair in fields))
        prompt_template = prompt_template or task_template
        if prompt_template is None:
            raise ValueError(f"the server at {host}:{port} publishes no prompt template and none was given: pass "
                             "prompt_template (or task_template, the prompts of the task a pi05 was finetuned on)")
        self.spec = ControllerSpec(
            action_convention=str(served.get("action_convention", "pd_ee_delta_pose")),
            chunk_len=chunk_len or served_horizon,
            action_dim=int(served.get("action_dim", 7)),
            needs_images=bool(served.get("needs_images", True)),
            prompt_template=prompt_template,
        )
        self._client_id = uuid.uuid4().hex
        self._seeds: list[int] = []
        self._episodes: list[int] = []  # per env slot: a number no earlier episode of this client had
        self._next_episode = 0

    def reset(self, seeds: Sequence[int]) -> None:
        """Start new episodes: record each env slot's seed and a new episode number, which the server keys
        its per-slot controller state on (a server started by ``sb3-memret serve`` resets it with the seed)."""
        self._seeds = [int(seed) for seed in seeds]
        self._episodes = [self._new_episode() for _ in seeds]

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        """Start new episodes in some slots only: they get new episode numbers, the others keep theirs."""
        self._check_env_ids(env_ids, seeds, len(self._seeds))
        for i, seed in zip(env_ids, seeds):
            self._seeds[i], self._episodes[i] = int(seed), self._new_episode()

    def __copy__(self) -> "OpenPIController":
        """A copy on the same connection that the server tells apart (its own client id, hence its own slots)."""
        twin = object.__new__(type(self))
        twin.__dict__.update(self.__dict__, _client_id=uuid.uuid4().hex, _seeds=[], _episodes=[])
        return twin

    def _new_episode(self) -> int:
        self._next_episode += 1
        return self._next_episode - 1

    def close(self) -> None:
        self.client.close()

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(self._seeds) != len(prompts):
            raise RuntimeError(f"reset() was called for {len(self._seeds)} envs but act() got {len(prompts)} prompts")
        requests = [pi05_libero_request(obs, i, p, self.spec.needs_images)
                    | {CLIENT_KEY: self._client_id, ENV_KEY: i, EPISODE_KEY: self._episodes[i], SEED_KEY: self._seeds[i]}
                    for i, p in enumerate(prompts)]
        return np.stack([self._chunk(self.client.infer(request)) for request in requests])

    def _chunk(self, reply: dict[str, Any]) -> np.ndarray:
        """The reply's action chunk, refused unless it is (chunk_len, 7) as the env's controller takes it."""
        if "actions" not in reply:
            raise PolicyServerError(
                f"openpi server at {self.client.uri} replied without 'actions': keys {sorted(reply)}")
        actions = np.asarray(reply["actions"], dtype=np.float32)
        expected = (self.spec.chunk_len, self.spec.action_dim)
        if actions.shape != expected:
            raise PolicyServerError(
                f"openpi server at {self.client.uri} returned actions of shape {actions.shape}, expected {expected}: "
                f"{self.spec.action_dim}-D {self.spec.action_convention} actions, chunks of {self.spec.chunk_len} "
                "(pass chunk_len= to match the served model's action horizon; actions are never transformed here)"
            )
        return actions


def api_key_header() -> dict[str, str] | None:
    """The ``Authorization`` header openpi's client sends for an API key, from ``$SB3_MEMRET_SERVE_API_KEY``."""
    key = os.environ.get(API_KEY_ENV)
    return {"Authorization": f"Api-Key {key}"} if key else None


def pi05_libero_request(obs: Obs, i: int, prompt: str, with_images: bool = True) -> dict[str, Any]:
    """Env ``i`` of a batched DrawerCubeTakeOut-v1 observation as one pi05_libero request, plus the drawer
    openings and cube detection when the observation has them."""
    request: dict[str, Any] = {key: _camera_image(obs, camera, i) for key, camera in CAMERAS.items()} if with_images else {}
    extra = obs.get("extra", {})
    request.update({key: as_numpy(extra[part])[i].astype(np.float32) for key, part in EXTRA_STATE.items()
                    if part in extra})
    state = as_numpy(obs["agent"]["eef_state"])[i].astype(np.float32)
    if state.shape != (STATE_DIM,):
        raise ValueError(f"agent/eef_state of env {i} has shape {state.shape}; pi05_libero takes ({STATE_DIM},)")
    request["observation/state"] = state
    request["prompt"] = prompt
    return request


def _camera_image(obs: Obs, camera: str, i: int) -> np.ndarray:
    rgb = obs.get("sensor_data", {}).get(camera, {}).get("rgb")
    if rgb is None:
        raise ValueError(
            f"the observation has no {camera} image (sensor_data/{camera}/rgb) and π0.5 needs both cameras; "
            + RENDER_HINT
        )
    image = as_numpy(rgb)[i]
    if image.shape != IMAGE_SHAPE or image.dtype != np.uint8:
        raise ValueError(
            f"{camera} image of env {i} is {image.dtype}{image.shape}; pi05_libero takes uint8{IMAGE_SHAPE}")
    return np.ascontiguousarray(image)
