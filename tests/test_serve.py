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
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("openpi_server", reason="openpi-server is not installed (pip install --no-deps openpi-server)")

import websockets.sync.client  # noqa: E402
from openpi_client import msgpack_numpy  # noqa: E402
from openpi_server import WebsocketPolicyServer  # noqa: E402

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.openpi import PolicyServerClient, PolicyServerError  # noqa: E402
from sb3_memret.tasks.drawer.expert import ScriptedDrawerController  # noqa: E402
from sb3_memret.tasks.drawer.prompts import condition_prompt  # noqa: E402
from conftest import drawer_episode  # noqa: E402
from sb3_memret.physics.chunks import execute_chunk
from sb3_memret.stage1.serve import ControllerPolicy, serve, serve_until_stopped  # noqa: E402
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


def serve_in_thread(controller: str) -> int:
    """openpi's WebsocketPolicyServer around ControllerPolicy(controller), in a daemon thread; its port."""
    policy, port = ControllerPolicy(controller, "drawer"), free_port()
    server = WebsocketPolicyServer(policy, host="127.0.0.1", port=port, metadata=policy.metadata)
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
    """``sb3-memret serve CONTROLLER`` in a process of its own, answering on its port."""
    port = free_port()
    command = [str(Path(sys.executable).parent / "sb3-memret"), "serve", controller, "--host", "127.0.0.1",
               "--port", str(port)]
    # Ctrl-C must reach it even where the tests run with SIGINT ignored (a shell's background job passes that on)
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
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


def test_the_cli_serves_the_scripted_expert_for_a_whole_episode(task_env):
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
    assert lines[0] == f"serving scripted on ws://127.0.0.1:{port} (openpi protocol; Ctrl-C stops)"
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
