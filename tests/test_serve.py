"""Serving controllers over openpi's protocol with openpi's own server, end to end through the real client."""

from __future__ import annotations

import asyncio
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

from openpi_server import WebsocketPolicyServer  # noqa: E402

from sb3_memret.controllers import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.openpi import PolicyServerClient, PolicyServerError  # noqa: E402
from sb3_memret.controllers.scripted import ScriptedDrawerController  # noqa: E402
from sb3_memret.prompts import condition_prompt  # noqa: E402
from sb3_memret.rollout import evaluate_condition, execute_chunk  # noqa: E402
from sb3_memret.stage1.serve import ControllerPolicy  # noqa: E402

DECISIONS = 6  # enough for the scripted expert to leave its first phase


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
    policy, port = ControllerPolicy(controller), free_port()
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
    controller = make_controller(f"openpi://127.0.0.1:{scripted_server}")
    assert controller.client.metadata["server"] == "sb3-memret"
    assert controller.client.metadata["controller"] == "scripted"
    assert controller.spec == ScriptedDrawerController().spec  # chunk 32, 7-D, pd_ee_delta_pose, no images, template
    assert controller.spec.chunk_len == 32 and not controller.spec.needs_images


def record(env, prompt: str, seed: int, layer: int, decisions: int = DECISIONS) -> list[tuple[dict, np.ndarray]]:
    """(observation, chunk) at each decision of the in-process scripted expert driving the real task."""
    controller = ScriptedDrawerController()
    obs, _ = env.reset(seed=seed, options={"target_layer": layer})
    controller.reset([seed])
    trajectory = []
    for _ in range(decisions):
        chunk = controller.act(obs, [prompt])[0]
        trajectory.append((obs, chunk))
        obs = execute_chunk(env, chunk[:8]).obs
    fresh = ScriptedDrawerController()
    fresh.reset([seed])
    assert not np.allclose(fresh.act(obs, [prompt])[0], controller.act(obs, [prompt])[0])  # the plan's history matters
    return trajectory


def test_each_env_slot_keeps_its_own_episode(scripted_server, task_env):
    """Two slots through one connection replay two in-process episodes exactly, and a reset starts both afresh."""
    prompts = [condition_prompt("oracle", 3), condition_prompt("wrong", 2)]
    episodes = [record(task_env, prompts[0], 1, 3), record(task_env, prompts[1], 2, 2)]
    remote = make_controller(f"openpi://127.0.0.1:{scripted_server}")
    for _ in range(2):  # the second time round, reset must have dropped the first round's plans
        remote.reset([1, 2])
        for (obs_a, chunk_a), (obs_b, chunk_b) in zip(*episodes):
            batch = {group: {key: np.concatenate([as_numpy(obs_a[group][key]), as_numpy(obs_b[group][key])])
                             for key in obs_a[group]} for group in ("agent", "extra")}
            np.testing.assert_allclose(remote.act(batch, prompts), np.stack([chunk_a, chunk_b]), atol=1e-6)


def test_a_plain_openpi_client_is_one_continuing_episode(task_env):
    """Requests without the episode keys all go to slot 0, whose episode never restarts."""
    client = PolicyServerClient("127.0.0.1", serve_in_thread("scripted"))
    prompt = condition_prompt("oracle", 2)
    for obs, chunk in record(task_env, prompt, 4, 2):
        np.testing.assert_allclose(client.infer(state_request(obs, prompt))["actions"], chunk, atol=1e-6)
    client.close()


def test_a_slot_is_reset_with_its_seed_when_its_episode_changes(monkeypatch, task_env):
    seeds = []
    reset = ScriptedDrawerController.reset
    monkeypatch.setattr(ScriptedDrawerController, "reset", lambda self, s: (seeds.append(list(s)), reset(self, s))[1])
    policy = ControllerPolicy("scripted")
    obs, _ = task_env.reset(seed=0)
    request = state_request(obs, condition_prompt("oracle", 1)) | {"sb3_memret/client": "c", "sb3_memret/env": 1}
    for episode, seed in ((0, 7), (0, 7), (1, 9)):
        policy.infer(request | {"sb3_memret/episode": episode, "sb3_memret/seed": seed})
    assert seeds == [[7], [9]]


def test_the_server_refuses_drift_and_missing_keys(scripted_server, task_env):
    """The client refuses a drifted prompt itself; the server also refuses it, and names a missing key."""
    controller = make_controller(f"openpi://127.0.0.1:{scripted_server}")
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
    remote, local = make_controller(f"openpi://127.0.0.1:{port}"), make_controller("learned-state")
    assert remote.spec == local.spec
    obs, _ = task_env.reset(seed=3, options={"target_layer": 1})
    batch = {k: {kk: np.repeat(np.asarray(vv), 2, axis=0) for kk, vv in v.items()} for k, v in obs.items()}
    prompts = [condition_prompt("oracle", 1), condition_prompt("none", 1)]
    for controller in (remote, local):
        controller.reset([3, 4])
    np.testing.assert_allclose(remote.act(batch, prompts), local.act(batch, prompts), atol=1e-5)


def test_the_cli_serves_the_scripted_expert_for_a_whole_episode(task_env):
    port = free_port()
    command = [str(Path(sys.executable).parent / "sb3-memret"), "serve", "scripted", "--host", "127.0.0.1",
               "--port", str(port)]
    # Ctrl-C must reach it even where the tests run with SIGINT ignored (a shell's background job passes that on)
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        wait_healthy(port, process=process)
        remote = make_controller(f"openpi://127.0.0.1:{port}")
        served = evaluate_condition(remote, "oracle", episodes=1, layers=[2], env=task_env)
        in_process = evaluate_condition(ScriptedDrawerController(), "oracle", episodes=1, layers=[2], env=task_env)
        assert served == in_process and served[0].success
        remote.close()
    finally:
        process.send_signal(signal.SIGINT)  # Ctrl-C
        _, stderr = process.communicate(timeout=30)
    lines = stderr.decode().strip().splitlines()
    assert lines[0] == f"serving scripted on ws://127.0.0.1:{port} (openpi protocol; Ctrl-C stops)"
    assert process.returncode == 130 and "Traceback" not in stderr.decode()


def test_a_bad_controller_is_one_line():
    from click.testing import CliRunner

    from sb3_memret.cli import main

    result = CliRunner().invoke(main, ["serve", "pi0", "--port", "1"], prog_name="sb3-memret")
    assert result.exit_code == 2 and "unknown controller 'pi0'" in result.output
    assert len(result.output.strip().splitlines()) == 1
