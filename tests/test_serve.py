"""Serving controllers over openpi's protocol with openpi's own server, end to end through the real client."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
import uuid
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("openpi_server", reason="openpi-server is not installed (pip install --no-deps openpi-server)")

import websockets.sync.client  # noqa: E402
from openpi_client import msgpack_numpy  # noqa: E402
from openpi_client.websocket_client_policy import WebsocketClientPolicy  # noqa: E402
from openpi_server import WebsocketPolicyServer  # noqa: E402

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.openpi import API_KEY_ENV, PolicyServerClient, PolicyServerError  # noqa: E402
from sb3_memret.tasks.drawer.expert import ScriptedDrawerController  # noqa: E402
from sb3_memret.tasks.drawer.prompts import condition_prompt  # noqa: E402
from conftest import drawer_episode  # noqa: E402
from sb3_memret.physics.chunks import execute_chunk
from sb3_memret.stage1.serve import (MAX_PROMPT_CHARS, MAX_REQUEST_BYTES, ControllerPolicy,  # noqa: E402
                                     GuardedPolicyServer, is_loopback, serve, serve_until_stopped)
from sb3_memret.common.workers import StopRequested, stop_signals_interrupt  # noqa: E402

DECISIONS = 6  # enough for the scripted expert to leave its first phase
EXIT_BOUND = 60.0  # s a served controller may take to exit after one stop signal: generous, it is no benchmark


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_healthy(port: int, timeout: float = 120.0, process: subprocess.Popen | None = None) -> None:
    """Wait for openpi's ``/healthz`` endpoint (and fail early if the server process exited)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if process is not None and process.poll() is not None:
            raise RuntimeError(f"server exited: {process.stderr.read().decode()}")
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=1) as reply:
                if reply.status == 200:
                    return
        except OSError:
            time.sleep(0.2)
    raise TimeoutError(f"no server on port {port}")


def serve_in_thread(controller: str | ControllerPolicy, api_key: str | None = None) -> int:
    """The server ``serve`` runs around ``controller`` (a spec, or a ControllerPolicy), in a daemon thread; its
    port."""
    policy = controller if isinstance(controller, ControllerPolicy) else ControllerPolicy(controller, "drawer")
    port = free_port()
    server = GuardedPolicyServer(policy, "127.0.0.1", port, api_key)
    threading.Thread(target=lambda: asyncio.run(server.run()), daemon=True).start()
    wait_healthy(port)
    return port


@pytest.fixture(scope="module")
def scripted_server() -> int:
    return serve_in_thread("scripted")


def state_request(obs: dict, prompt: str, i: int = 0) -> dict:
    """What a plain openpi client would send for env ``i``: pi05_libero's state and prompt plus the task state."""
    return {"observation/state": as_numpy(obs["agent"]["eef_state"])[i], "prompt": prompt,
            "observation/drawer_opening": as_numpy(obs["extra"]["drawer_opening"])[i],
            "observation/target_detection": as_numpy(obs["extra"]["target_detection"])[i]}


def test_metadata_describes_the_served_controller(scripted_server):
    controller = make_controller(f"openpi://127.0.0.1:{scripted_server}", "drawer")
    assert controller.client.metadata["server"] == "sb3-memret"
    assert controller.client.metadata["controller"] == "scripted"
    assert controller.spec == ScriptedDrawerController().spec  # chunk 32, 7-D, pd_ee_delta_pose, no images, template
    assert controller.spec.chunk_len == 32 and not controller.spec.needs_images


def record(env, prompts: list[str], seed: int, layer: int,
           history_matters: bool = False) -> list[tuple[dict, np.ndarray, str]]:
    """(observation, chunk, prompt) at each decision of the in-process scripted expert driving the real task, one
    decision per prompt. ``history_matters``: check that at the end a fresh expert would act otherwise (its plan
    remembers what the observation no longer shows, e.g. the drawer a replaced prompt had it open), so a server that
    mixed up its slots' plans could not replay the episode."""
    controller = ScriptedDrawerController()
    obs, _ = env.reset(seed=seed, options={"target_layer": layer})
    controller.reset([seed])
    trajectory = []
    for prompt in prompts:
        chunk = controller.act(obs, [prompt])[0]
        trajectory.append((obs, chunk, prompt))
        obs = execute_chunk(env, chunk[:8]).obs
    if history_matters:
        fresh = ScriptedDrawerController()
        fresh.reset([seed])
        assert not np.allclose(fresh.act(obs, [prompts[-1]])[0], controller.act(obs, [prompts[-1]])[0])
    return trajectory


def test_each_env_slot_keeps_its_own_episode(scripted_server, task_env):
    """Two slots through one connection replay two in-process episodes exactly, and a reset starts both afresh."""
    # a wrong fact until the expert pulls that drawer open, then the true one: it must close the wrong drawer first,
    # which only its plan remembers
    switched = [condition_prompt("oracle", 1)] * 10 + [condition_prompt("oracle", 3)] * 2
    episodes = [record(task_env, switched, 1, 3, history_matters=True),
                record(task_env, [condition_prompt("wrong", 2)] * len(switched), 2, 2)]
    remote = make_controller(f"openpi://127.0.0.1:{scripted_server}", "drawer")
    for _ in range(2):  # the second time round, reset must have dropped the first round's plans
        remote.reset([1, 2])
        for (obs_a, chunk_a, prompt_a), (obs_b, chunk_b, prompt_b) in zip(*episodes):
            batch = {group: {key: np.concatenate([as_numpy(obs_a[group][key]), as_numpy(obs_b[group][key])])
                             for key in obs_a[group]} for group in ("agent", "extra")}
            np.testing.assert_allclose(remote.act(batch, [prompt_a, prompt_b]), np.stack([chunk_a, chunk_b]), atol=1e-6)


def test_a_plain_openpi_client_is_one_continuing_episode(task_env):
    """Requests without the episode keys all go to slot 0, whose episode never restarts."""
    client = PolicyServerClient("127.0.0.1", serve_in_thread("scripted"))
    prompt = condition_prompt("oracle", 2)
    for obs, chunk, _ in record(task_env, [prompt] * DECISIONS, 4, 2):
        np.testing.assert_allclose(client.infer(state_request(obs, prompt))["actions"], chunk, atol=1e-6)
    client.close()


def test_a_slot_is_reset_with_its_seed_when_its_episode_changes(monkeypatch, task_env):
    seeds = []
    reset = ScriptedDrawerController.reset
    monkeypatch.setattr(ScriptedDrawerController, "reset", lambda self, s: (seeds.append(list(s)), reset(self, s))[1])
    policy = ControllerPolicy("scripted", "drawer")
    obs, _ = task_env.reset(seed=0)
    request = state_request(obs, condition_prompt("oracle", 1)) | {"sb3_memret/client": "c", "sb3_memret/env": 1}
    for episode, seed in ((0, 7), (0, 7), (1, 9)):
        policy.infer(request | {"sb3_memret/episode": episode, "sb3_memret/seed": seed})
    assert seeds == [[7], [9]]


def test_the_server_refuses_drift_and_missing_keys(scripted_server, task_env):
    """The client refuses a drifted prompt itself; the server also refuses it, and names a missing key."""
    controller = make_controller(f"openpi://127.0.0.1:{scripted_server}", "drawer")
    obs, _ = task_env.reset(seed=0)
    controller.reset([0])
    drifted = "pick out the cube. the cube is inside drawer layer 2."
    with pytest.raises(ValueError, match="matches no trained template"):
        controller.act(obs, [drifted])

    client = PolicyServerClient("127.0.0.1", scripted_server)
    with pytest.raises(PolicyServerError, match="matches no trained template"):
        client.infer(state_request(obs, drifted))
    request = state_request(obs, condition_prompt("oracle", 1))
    del request["observation/target_detection"]
    with pytest.raises(PolicyServerError, match="the request lacks 'observation/target_detection'"):
        client.infer(request)
    with pytest.raises(PolicyServerError, match=r"'observation/state' is float32\(3,\); expected float32\(8,\)"):
        client.infer(state_request(obs, condition_prompt("oracle", 1)) | {"observation/state": np.zeros(3, np.float32)})
    client.close()


def test_a_stateless_learned_controller_over_the_wire(task_env):
    port = serve_in_thread("learned-state")
    remote, local = make_controller(f"openpi://127.0.0.1:{port}", "drawer"), make_controller("learned-state", "drawer")
    assert remote.spec == local.spec
    obs, _ = task_env.reset(seed=3, options={"target_layer": 1})
    batch = {k: {kk: np.repeat(np.asarray(vv), 2, axis=0) for kk, vv in v.items()} for k, v in obs.items()}
    prompts = [condition_prompt("oracle", 1), condition_prompt("none", 1)]
    for controller in (remote, local):
        controller.reset([3, 4])
    np.testing.assert_allclose(remote.act(batch, prompts), local.act(batch, prompts), atol=1e-5)


class _SigtermWhenCollected:
    """Raises SIGTERM from its ``__del__``, so that the signal's Python handler runs inside it: as when the signal
    arrives while the event loop collects a hung-up client's transport (or drops a weak set's entry)."""

    def __del__(self) -> None:
        signal.raise_signal(signal.SIGTERM)


class SigtermInInference(ControllerPolicy):
    """The scripted expert, whose every inference is interrupted by a SIGTERM caught inside a ``__del__``."""

    def infer(self, request: dict) -> dict:
        _SigtermWhenCollected()  # collected at once, in the event loop's thread
        return super().infer(request)


def test_a_sigterm_caught_inside_a_del_stops_the_server_after_the_inference_in_flight(task_env):
    """A ``__del__`` swallows whatever its code raises; the stop signal must survive that (it once did not, and the
    server served on until a second SIGTERM). serve() runs here, in the main thread, under the CLI's signal handling."""
    port, lines, seen = free_port(), [], {}
    obs, _ = task_env.reset(seed=0)
    request = state_request(obs, condition_prompt("oracle", 1))

    def client() -> None:
        try:
            wait_healthy(port)
            with websockets.sync.client.connect(f"ws://127.0.0.1:{port}", compression=None, max_size=None) as ws:
                ws.recv(timeout=EXIT_BOUND)  # metadata
                ws.send(msgpack_numpy.packb(request))
                seen["reply"] = msgpack_numpy.unpackb(ws.recv(timeout=EXIT_BOUND))
                ws.recv(timeout=EXIT_BOUND)
        except websockets.exceptions.ConnectionClosed as closed:
            seen["close code"] = closed.rcvd.code if closed.rcvd else None
        except BaseException as err:  # reported below, in the test's thread
            seen["error"] = err

    def second_sigterm() -> None:  # only if the first was lost: it ends the server, and the test fails
        seen["second SIGTERM"] = True
        os.kill(os.getpid(), signal.SIGTERM)

    watchdog = threading.Timer(EXIT_BOUND, second_sigterm)
    thread = threading.Thread(target=client)
    with stop_signals_interrupt():
        watchdog.start()
        thread.start()
        try:
            with pytest.raises(StopRequested):
                serve(SigtermInInference("scripted", "drawer"), "127.0.0.1", port, log=lines.append)
        finally:
            watchdog.cancel()
    thread.join(EXIT_BOUND)
    assert "second SIGTERM" not in seen and "error" not in seen, seen
    assert seen["reply"]["actions"].shape == (32, 7)  # the inference in flight answered
    assert seen["close code"] == 1001  # then the server went away
    assert lines[0].startswith("SIGTERM: stopping;") and lines[1].startswith("stopped on SIGTERM after")


def silent_client(port: int) -> socket.socket:
    """A websocket client that, once the server has greeted it, never reads or answers again (a hung peer)."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=EXIT_BOUND)
    sock.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                 b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n")
    received = b""
    while b"\r\n\r\n" not in received or received.endswith(b"\r\n\r\n"):  # the 101 reply, then the metadata
        received += sock.recv(65536)
    assert received.startswith(b"HTTP/1.1 101"), received
    return sock


@pytest.mark.parametrize("second_signal", [None, signal.SIGINT])
def test_a_peer_that_never_closes_is_cut_after_the_grace_or_a_second_signal(second_signal):
    """Closing waits for each peer's closing handshake; one that never answers is cut when the grace runs out (or
    at once on a second signal), and no server task is left pending."""
    port, lines, started = free_port(), [], threading.Event()
    server = WebsocketPolicyServer(ControllerPolicy("scripted", "drawer"), host="127.0.0.1", port=port)
    loop, signals = asyncio.new_event_loop(), asyncio.Queue()

    def log(line: str) -> None:
        lines.append(line)
        started.set()

    def run() -> None:
        grace = 0.5 if second_signal is None else EXIT_BOUND
        lines.append(loop.run_until_complete(serve_until_stopped(server.run(), signals, log, grace=grace)))

    thread = threading.Thread(target=run)
    thread.start()
    wait_healthy(port)
    peer = silent_client(port)
    try:
        loop.call_soon_threadsafe(signals.put_nowait, signal.SIGTERM)
        assert started.wait(EXIT_BOUND)
        if second_signal is not None:
            loop.call_soon_threadsafe(signals.put_nowait, second_signal)
        thread.join(EXIT_BOUND)
        assert not thread.is_alive()
        assert not asyncio.all_tasks(loop)  # every server task unwound
    finally:
        peer.close()
        if not loop.is_running():  # else the failure above says why
            loop.close()
    why = "0.5 s without closing" if second_signal is None else "a second SIGINT"
    assert lines[1].startswith("stopped on SIGTERM after") and f": {why} cut the connections still open" in lines[1]
    assert lines[2] == signal.SIGTERM


def start_cli_server(controller: str) -> tuple[subprocess.Popen, int]:
    """``sb3-memret serve CONTROLLER`` in a process of its own, answering on its port of its default host."""
    port = free_port()
    command = [str(Path(sys.executable).parent / "sb3-memret"), "serve", controller, "--port", str(port)]
    # Ctrl-C must reach it even where the tests run with SIGINT ignored (a shell's background job passes that on)
    environment = {name: value for name, value in os.environ.items() if name != API_KEY_ENV}  # no key: none checked
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=environment,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        wait_healthy(port, process=process)
    except BaseException:
        process.kill()
        process.communicate()
        raise
    return process, port


def stop_cli_server(process: subprocess.Popen, signum: int, bound: float = EXIT_BOUND) -> list[str]:
    """Send ``signum`` once and return the server's standard error lines; fails if it is still running after
    ``bound`` seconds (then kills it, so that a hang fails the test instead of stalling the suite)."""
    process.send_signal(signum)
    try:
        _, stderr = process.communicate(timeout=bound)
    except subprocess.TimeoutExpired:
        process.kill()
        _, stderr = process.communicate()
        pytest.fail(f"one {signal.Signals(signum).name} left the server running for {bound:g} s:\n{stderr.decode()}")
    return stderr.decode().strip().splitlines()


def test_the_cli_serves_the_scripted_expert_for_a_whole_episode_on_the_loopback_by_default(task_env):
    process, port = start_cli_server("scripted")
    try:
        remote = make_controller(f"openpi://127.0.0.1:{port}", "drawer")
        prompt = condition_prompt("oracle", 2)
        served = drawer_episode(task_env, remote, prompt, seed=0, layer=2)
        in_process = drawer_episode(task_env, ScriptedDrawerController(), prompt, seed=0, layer=2)
        assert served == in_process and served.success
        remote.close()
    finally:
        lines = stop_cli_server(process, signal.SIGINT)  # Ctrl-C
    assert lines[0] == f"serving scripted on ws://127.0.0.1:{port} (openpi protocol; Ctrl-C stops)"  # the loopback
    assert lines[1].startswith("SIGINT: stopping;") and lines[2].startswith("stopped on SIGINT after")
    assert process.returncode == 130 and not any("Traceback" in line for line in lines)


def test_one_sigterm_right_after_a_learned_controllers_episode_stops_the_cli_server(task_env):
    """The reported case: the client plays its (short) episode, hangs up, and the SIGTERM follows at once."""
    process, port = start_cli_server("learned-state")
    try:
        remote = make_controller(f"openpi://127.0.0.1:{port}", "drawer")
        obs, _ = task_env.reset(seed=3, options={"target_layer": 1})
        remote.reset([3])
        for _ in range(DECISIONS):
            obs = execute_chunk(task_env, remote.act(obs, [condition_prompt("oracle", 1)])[0][:8]).obs
        remote.close()
    finally:
        lines = stop_cli_server(process, signal.SIGTERM)
    assert lines[1].startswith("SIGTERM: stopping;") and lines[2].startswith("stopped on SIGTERM after")
    assert process.returncode == 143 and not any("Traceback" in line for line in lines)


def test_a_bad_controller_is_one_line():
    from click.testing import CliRunner

    from sb3_memret.cli import main

    result = CliRunner().invoke(main, ["serve", "pi0", "--port", "1"], prog_name="sb3-memret")
    assert result.exit_code == 2 and "unknown controller 'pi0'" in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_a_taken_port_is_one_line():
    from click.testing import CliRunner

    from sb3_memret.cli import main

    before = signal.getsignal(signal.SIGTERM)  # not SIG_DFL once an earlier test has started Ray in this process
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = CliRunner().invoke(main, ["serve", "scripted", "--host", "127.0.0.1", "--port", str(port)],
                                    prog_name="sb3-memret")
    assert result.exit_code == 2 and "Error: Invalid value for --port: cannot serve on 127.0.0.1" in result.output
    assert "address already in use" in result.output and "Traceback" not in result.output
    assert signal.getsignal(signal.SIGTERM) is before  # serve() put the handlers back


@pytest.mark.parametrize("host, loopback", [("127.0.0.1", True), ("127.0.0.2", True), ("::1", True),
                                            ("localhost", True), ("0.0.0.0", False), ("::", False), ("", False),
                                            ("192.0.2.7", False), ("robot.example.org", False)])
def test_only_loopback_addresses_count_as_the_loopback(host, loopback):
    assert is_loopback(host) is loopback


def invoke_cli(args: list[str], key: str | None = None):
    """``sb3-memret serve ARGS`` in this process, with ``key`` (or none) in the environment."""
    from click.testing import CliRunner

    from sb3_memret.cli import main

    return CliRunner().invoke(main, ["serve", *args], prog_name="sb3-memret", env={API_KEY_ENV: key})


@pytest.mark.parametrize("host", ["0.0.0.0", "192.0.2.7"])
def test_a_non_loopback_host_without_a_key_refuses_to_start(host):
    result = invoke_cli(["scripted", "--host", host, "--port", str(free_port())])
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1
    assert f"Invalid value for --host: host '{host}' is not a loopback address" in result.output
    assert "--api-key" in result.output and API_KEY_ENV in result.output
    with pytest.raises(ValueError, match="is not a loopback address"):
        serve(ControllerPolicy("scripted", "drawer"), host, free_port())


def test_a_key_that_cannot_travel_in_a_header_is_one_line_that_hides_it():
    result = invoke_cli(["scripted", "--host", "0.0.0.0", "--port", str(free_port())], key="two words")
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1
    assert "Invalid value for --api-key: the API key (9 characters) must be one or more printable" in result.output
    assert "two words" not in result.output


class CountingPolicy(ControllerPolicy):
    """The scripted expert, counting the requests that reach it and those that reach its controller."""

    def __init__(self) -> None:
        super().__init__("scripted", "drawer")
        self.requests = self.acted = 0

    def infer(self, request: dict) -> dict:
        self.requests += 1
        return super().infer(request)

    def _controller_for(self, request: dict):
        self.acted += 1
        return super()._controller_for(request)


def plain_request(prompt: str = condition_prompt("oracle", 1)) -> dict:
    """A valid state-only request, built by hand (the expert acts on any state)."""
    return {"observation/state": np.zeros(8, np.float32), "observation/drawer_opening": np.zeros(3, np.float32),
            "observation/target_detection": np.zeros(8, np.float32), "prompt": prompt}


@pytest.mark.filterwarnings("ignore:connect\\(\\) must be used as a context manager")  # openpi's client
def test_only_a_client_with_the_key_is_served_and_others_are_refused_at_the_handshake():
    policy = CountingPolicy()
    port = serve_in_thread(policy, api_key="s3cret-key")
    served = WebsocketClientPolicy("127.0.0.1", port, api_key="s3cret-key").infer(plain_request())
    assert served["actions"].shape == (32, 7)
    for key, status in ((None, 401), ("s3cret-kez", 403), ("s3cret-key-and-more", 403)):
        with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
            WebsocketClientPolicy("127.0.0.1", port, api_key=key)
        assert refused.value.response.status_code == status
    assert policy.requests == 1  # the refused clients never sent a message


def test_the_projects_client_sends_the_key_from_the_environment(monkeypatch):
    port = serve_in_thread("scripted", api_key="s3cret-key")
    monkeypatch.setenv(API_KEY_ENV, "s3cret-key")
    assert PolicyServerClient("127.0.0.1", port).infer(plain_request())["actions"].shape == (32, 7)
    monkeypatch.setenv(API_KEY_ENV, "wrong")
    with pytest.raises(PolicyServerError, match=f"HTTP 403: wrong API key\\); set {API_KEY_ENV} to the API key"):
        PolicyServerClient("127.0.0.1", port)


def largest_valid_request() -> dict:
    """Every key the server reads at its largest: both cameras, 8-byte state values, the longest prompt in 4-byte
    characters, the episode keys at their widest."""
    image = np.zeros((224, 224, 3), np.uint8)
    return {"observation/image": image, "observation/wrist_image": image,
            "observation/state": np.zeros(8), "observation/drawer_opening": np.zeros(3),
            "observation/target_detection": np.zeros(8), "prompt": "\U0001F9CA" * MAX_PROMPT_CHARS,
            "sb3_memret/client": uuid.uuid4().hex, "sb3_memret/env": 2**63 - 1, "sb3_memret/episode": 2**63 - 1,
            "sb3_memret/seed": 2**63 - 1}


def send_one(port: int, message: bytes) -> bytes | str:
    """The server's reply to ``message``, sent alone on a fresh connection."""
    with websockets.sync.client.connect(f"ws://127.0.0.1:{port}", compression=None, max_size=None) as ws:
        ws.recv(timeout=EXIT_BOUND)  # metadata
        ws.send(message)
        return ws.recv(timeout=EXIT_BOUND)


def test_a_message_over_the_largest_valid_request_is_closed_with_1009_unread():
    policy = CountingPolicy()
    port = serve_in_thread(policy)
    largest = msgpack_numpy.packb(largest_valid_request())
    assert len(largest) <= MAX_REQUEST_BYTES
    assert "malformed prompt" in send_one(port, largest)  # it reached the controller, which parsed the prompt
    with pytest.raises(websockets.exceptions.ConnectionClosed) as closed:
        send_one(port, b"\0" * (MAX_REQUEST_BYTES + 1))
    assert closed.value.rcvd.code == 1009
    assert policy.requests == policy.acted == 1


def test_an_over_long_prompt_is_refused_before_the_controller_parses_it():
    policy = CountingPolicy()
    client = PolicyServerClient("127.0.0.1", serve_in_thread(policy))
    with pytest.raises(PolicyServerError, match=f"'prompt' has 100000 characters; at most {MAX_PROMPT_CHARS} are"):
        client.infer(plain_request("x" * 100_000))  # no full stop: splitting it into sentences takes seconds
    with pytest.raises(ValueError, match=f"'prompt' has {MAX_PROMPT_CHARS + 1} characters"):
        policy.infer(plain_request("x" * (MAX_PROMPT_CHARS + 1)))
    with pytest.raises(ValueError, match=f"'prompt' is int; expected a str of at most {MAX_PROMPT_CHARS} characters"):
        policy.infer(plain_request(7))
    assert policy.acted == 0
    with pytest.raises(ValueError, match="malformed prompt"):  # at the limit: parsed, and refused there
        policy.infer(plain_request("x" * MAX_PROMPT_CHARS))
    client.close()
