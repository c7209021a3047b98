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

Exposure: ``serve`` binds the loopback (127.0.0.1) unless told another host, and there it needs an API key
(``check_exposure``): a client sends ``Authorization: Api-Key KEY`` (openpi's client does, given ``api_key``; the
project's reads ``SB3_MEMRET_SERVE_API_KEY``), and one without the key is refused at the handshake, 401 without a
key and 403 with another, before any message is read. A given key is checked on the loopback too; ``/healthz``
answers anyone. A message larger than the largest valid request (``MAX_REQUEST_BYTES``, 314 KiB) is refused by
websockets unread (close code 1009), and a prompt longer than ``MAX_PROMPT_CHARS`` before it is parsed.

Stopping: ``serve`` takes SIGINT and SIGTERM through the event loop, never as an exception raised wherever the
main thread happens to be (a ``__del__`` would swallow it, a callback cut half-way would leave the shutdown waiting
forever); one signal closes the connections, a second or ``STOP_GRACE`` seconds cut those that do not close.
"""

from __future__ import annotations

import asyncio
import copy
import hmac
import http
import ipaddress
import re
import signal
import sys
import threading
import time
from contextlib import contextmanager
from typing import Any, Callable, Coroutine, Iterator, Mapping

import numpy as np

from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers.base import FrozenController
from sb3_memret.controllers.observation import IMAGE_SHAPE, STATE_PARTS
from sb3_memret.controllers.openpi import (API_KEY_ENV, CAMERAS, CLIENT_KEY, ENV_KEY, EPISODE_KEY, EXTRA_STATE,
                                          SEED_KEY)
from sb3_memret.common.workers import STOP_SIGNALS, StopRequested
from sb3_memret.tasks import Task

try:
    import websockets.asyncio.server
    from openpi_server import WebsocketPolicyServer
    from websockets.asyncio.server import ServerConnection
    from websockets.http11 import Request, Response
except ImportError as err:
    raise ImportError(f"serving needs openpi-server ({err}); install it with `pip install --no-deps openpi-server`"
                      ) from err

STATE_KEY, PROMPT_KEY = "observation/state", "prompt"
SIZES = {key: len(names) for _, key, names in STATE_PARTS}  # eef_state 8, drawer_opening 3, target_detection 8
MAX_SLOTS = 4096  # per-slot controllers kept; the least recently used beyond this are dropped
STOP_GRACE = 15.0  # s for open connections to close after a stop signal; websockets' closing handshake waits <= 10 s
CUT_WAIT = 1.0  # s for cancelled server tasks to unwind before the loop closes
# twice the longest prompt the project builds (TraceShapeSeq's instruction and k=7 facts of five paths: ~2,000);
# parsing a 100,000-character one held the server for seconds
MAX_PROMPT_CHARS = 4096
FRAMING_BYTES = 4096  # msgpack's keys and array headers and the episode keys, with room to spare
# both cameras (any request may carry them: a plain openpi client always does), the state parts at up to 8 bytes a
# value, the longest prompt at up to 4 UTF-8 bytes a character: 321,688 bytes (314 KiB)
MAX_REQUEST_BYTES = (len(CAMERAS) * int(np.prod(IMAGE_SHAPE)) + 8 * sum(SIZES.values()) + 4 * MAX_PROMPT_CHARS
                     + FRAMING_BYTES)
API_KEY_RE = re.compile(r"[!-~]+")  # printable ASCII without spaces: it travels in an HTTP header


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
    """An openpi policy (``infer(obs) -> {"actions": ...}``) backed by a controller spec such as ``learned``, for
    ``task`` (a name or a ``Task``: whose expert ``scripted`` is, whose prompts and observations it takes)."""

    def __init__(self, controller: str, task: str | Task):
        self.controller_spec = controller
        self._template = make_controller(controller, task)  # a bad spec fails here, before serving
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
                                    "fact_templates": list(template.fact_templates),
                                    "fields": [list(pair) for pair in template.fields]}}

    def infer(self, request: dict[str, Any]) -> dict[str, np.ndarray]:
        """One request -> ``{"actions": (chunk_len, action_dim)}`` from its slot's controller."""
        obs = self._observation(request)
        prompt = _prompt(request[PROMPT_KEY])
        return {"actions": self._controller_for(request).act(obs, [prompt])[0]}

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
    """``request[key]`` with a batch axis of one, refused unless it has ``shape`` and ``dtype`` (state: any real
    number of up to 8 bytes, as ``MAX_REQUEST_BYTES`` counts it)."""
    value = np.asarray(request[key])
    real = value.dtype.kind in "iuf" and value.dtype.itemsize <= 8
    if value.shape != shape or not (value.dtype == np.uint8 if dtype is np.uint8 else real):
        raise ValueError(f"request key {key!r} is {value.dtype}{value.shape}; expected {np.dtype(dtype)}{shape}")
    return value.astype(dtype)[None]


def _prompt(value: Any) -> str:
    """The request's prompt, refused unless it is a string of at most ``MAX_PROMPT_CHARS``: checked before the
    controller parses it, which takes seconds on a long one."""
    if not isinstance(value, str):
        raise ValueError(f"request key {PROMPT_KEY!r} is {type(value).__name__}; expected a str of at most "
                         f"{MAX_PROMPT_CHARS} characters")
    if len(value) > MAX_PROMPT_CHARS:
        raise ValueError(f"request key {PROMPT_KEY!r} has {len(value)} characters; at most {MAX_PROMPT_CHARS} are "
                         "accepted (an instruction and its facts take about half that)")
    return value


def is_loopback(host: str) -> bool:
    """Whether ``host`` is ``localhost`` or a loopback address (127.0.0.0/8, ::1): only this machine reaches it. Any
    other name may resolve to an exposed address, so it counts as exposed."""
    try:
        return host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_exposure(host: str, api_key: str | None) -> None:
    """Refuse a non-loopback ``host`` without an API key (anyone reaching it could drive the controller) and a key
    that cannot travel in an HTTP header."""
    if api_key is not None and not API_KEY_RE.fullmatch(api_key):
        raise ValueError(f"the API key ({len(api_key)} characters) must be one or more printable ASCII characters "
                         "without spaces: it travels in an HTTP header")
    if api_key is None and not is_loopback(host):
        raise ValueError(f"host {host!r} is not a loopback address, so serving there needs an API key (--api-key "
                         f"KEY, or the environment variable {API_KEY_ENV}); the loopback, 127.0.0.1, needs none")


class GuardedPolicyServer(WebsocketPolicyServer):
    """openpi's server, which serves messages of any size to anyone, with a size limit (``MAX_REQUEST_BYTES``) and,
    given ``api_key``, a key check at the handshake."""

    def __init__(self, policy: ControllerPolicy, host: str = "127.0.0.1", port: int = 8000,
                 api_key: str | None = None):
        check_exposure(host, api_key)
        super().__init__(policy, host=host, port=port, metadata=policy.metadata)
        self._expected = None if api_key is None else f"Api-Key {api_key}".encode()

    async def run(self) -> None:
        """openpi's ``run`` with ``max_size`` and ``_admit``: websockets closes an oversize message with 1009 unread."""
        async with websockets.asyncio.server.serve(self._handler, self._host, self._port, compression=None,
                                                   max_size=MAX_REQUEST_BYTES, process_request=self._admit) as server:
            await server.serve_forever()

    def _admit(self, connection: ServerConnection, request: Request) -> Response | None:
        """openpi's ``/healthz`` reply; else, with a key set, refuse a handshake without it: 401 with no key, 403 with
        another (or several)."""
        if request.path == "/healthz":
            return connection.respond(http.HTTPStatus.OK, "OK\n")
        if self._expected is None:
            return None
        sent = request.headers.get_all("Authorization")
        if not sent:
            return connection.respond(http.HTTPStatus.UNAUTHORIZED,
                                      "this server needs an API key: send the header 'Authorization: Api-Key KEY'\n")
        if len(sent) != 1 or not hmac.compare_digest(sent[0].encode(), self._expected):
            return connection.respond(http.HTTPStatus.FORBIDDEN, "wrong API key\n")
        return None


def print_to_stderr(line: str) -> None:
    """One line to standard error, where the CLI's other messages go."""
    print(line, file=sys.stderr, flush=True)


def serve(policy: ControllerPolicy, host: str = "127.0.0.1", port: int = 8000, api_key: str | None = None,
          log: Callable[[str], None] = print_to_stderr) -> None:
    """Serve a controller (a ``ControllerPolicy``) on ws://host:port (``GuardedPolicyServer``) until SIGINT or SIGTERM,
    then stop it (see ``serve_until_stopped``) and raise that signal's interrupt: KeyboardInterrupt for Ctrl-C,
    ``StopRequested`` for SIGTERM. Only the main thread receives signals, so only it may call this."""
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("serve() stops on SIGINT and SIGTERM, which only the main thread receives; in another "
                           "thread run GuardedPolicyServer(...).run() as a task and cancel it")
    server = GuardedPolicyServer(policy, host, port, api_key)
    loop = asyncio.new_event_loop()
    signals: asyncio.Queue[int] = asyncio.Queue()
    try:
        with _signals_to(loop, signals):
            signum = loop.run_until_complete(serve_until_stopped(server.run(), signals, log))
    finally:
        loop.close()
    raise KeyboardInterrupt if signum == signal.SIGINT else StopRequested(signum)


async def serve_until_stopped(server: Coroutine[Any, Any, None], signals: asyncio.Queue[int],
                              log: Callable[[str], None], grace: float = STOP_GRACE) -> int:
    """Run ``server`` (openpi's ``WebsocketPolicyServer.run()``) until a signal number arrives in ``signals``, then
    cancel it: it stops accepting and closes the open connections once any inference in progress has replied. Waits
    for that up to ``grace`` seconds or until a second signal, then cuts what is left (its tasks are cancelled, given
    ``CUT_WAIT`` seconds to unwind, and left behind) so that no connection keeps the process alive. Returns the first
    signal's number."""
    serving = asyncio.create_task(server)
    first = asyncio.create_task(signals.get())
    await asyncio.wait([serving, first], return_when=asyncio.FIRST_COMPLETED)
    if not first.done():  # serving ended by itself: it could not listen (the port is taken, say)
        await _cancel([first], CUT_WAIT)
        serving.result()
        raise RuntimeError("openpi's server stopped serving without a stop signal")
    name, started = signal.Signals(first.result()).name, time.monotonic()
    log(f"{name}: stopping; open connections close once any inference in progress has replied (a second "
        f"{name}, or {grace:g} s, cuts them)")
    serving.cancel()
    second = asyncio.create_task(signals.get())
    await asyncio.wait([serving, second], timeout=grace, return_when=asyncio.FIRST_COMPLETED)
    if serving.done():
        await _cancel([second], CUT_WAIT)
        if not serving.cancelled() and serving.exception() is not None:
            raise serving.exception()
        log(f"stopped on {name} after {time.monotonic() - started:.1f} s")
        return first.result()
    why = f"a second {signal.Signals(second.result()).name}" if second.done() else f"{grace:g} s without closing"
    left = [task for task in asyncio.all_tasks() if task is not asyncio.current_task()]
    await _cancel(left, CUT_WAIT)
    log(f"stopped on {name} after {time.monotonic() - started:.1f} s: {why} cut the connections still open")
    return first.result()


async def _cancel(tasks: list[asyncio.Task], wait: float) -> None:
    """Cancel ``tasks`` until they end or ``wait`` seconds pass: a cancelled connection awaits its closing handshake
    on the way out, which needs one more cancel (a task the loop drops while pending is logged as an error)."""
    deadline = time.monotonic() + wait
    pending = set(tasks)
    while pending and time.monotonic() < deadline:
        for task in pending:
            task.cancel()
        _, pending = await asyncio.wait(pending, timeout=min(0.05, max(deadline - time.monotonic(), 0)))


@contextmanager
def _signals_to(loop: asyncio.AbstractEventLoop, signals: asyncio.Queue[int]) -> Iterator[None]:
    """Within, SIGINT and SIGTERM (unless ignored) put their number in ``signals`` from ``loop``'s own turn; the
    previous handlers come back after.

    A Python handler that raises (the CLI's SIGTERM, Ctrl-C's KeyboardInterrupt) runs at whatever line the main
    thread is on. In an event loop that can be a transport's ``__del__``, which swallows the exception and with it
    the stop (the server then serves on), or a callback cut half-way, after which the loop's shutdown waits forever
    for a connection that will never report closed.
    """
    previous = {signum: signal.getsignal(signum) for signum in STOP_SIGNALS
                if signal.getsignal(signum) is not signal.SIG_IGN}  # a background job's ignored Ctrl-C stays ignored
    for signum in previous:
        loop.add_signal_handler(signum, signals.put_nowait, signum)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            loop.remove_signal_handler(signum)
            signal.signal(signum, handler)


__all__ = ["MAX_PROMPT_CHARS", "MAX_REQUEST_BYTES", "ControllerPolicy", "GuardedPolicyServer", "check_exposure",
           "is_loopback", "serve", "serve_until_stopped"]
