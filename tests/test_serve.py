"""Serving controllers over openpi's protocol with openpi's own server, end to end through the real client."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from sb3_memret.controllers import make_controller
from sb3_memret.controllers.scripted import ScriptedDrawerController
from sb3_memret.prompts import condition_prompt
from sb3_memret.rollout import run_episode
from sb3_memret.stage1.serve import ControllerPolicy


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_healthy(port: int, timeout: float = 180.0, process: subprocess.Popen | None = None) -> None:
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


@pytest.fixture(scope="module")
def scripted_server():
    """`serve scripted` in a thread: openpi's WebsocketPolicyServer around ControllerPolicy."""
    import asyncio

    from openpi_server import WebsocketPolicyServer

    policy, port = ControllerPolicy("scripted"), free_port()
    server = WebsocketPolicyServer(policy, host="127.0.0.1", port=port, metadata=policy.metadata)
    threading.Thread(target=lambda: asyncio.run(server.run()), daemon=True).start()
    wait_healthy(port)
    return port


def test_metadata_describes_the_served_controller(scripted_server):
    controller = make_controller(f"openpi://127.0.0.1:{scripted_server}")
    assert controller.client.metadata["controller"] == "scripted"
    assert controller.spec.chunk_len == 32 and not controller.spec.needs_images
    assert controller.spec.prompt_template == ScriptedDrawerController().spec.prompt_template


def test_each_env_slot_keeps_its_own_episode(scripted_server, task_env):
    """Two slots through one connection act exactly like an in-process scripted controller with two envs."""
    remote, local = make_controller(f"openpi://127.0.0.1:{scripted_server}"), ScriptedDrawerController()
    obs, _ = task_env.reset(seed=1, options={"cube_layer": 3})
    batch = {k: {kk: np.repeat(np.asarray(vv), 2, axis=0) for kk, vv in v.items()} for k, v in obs.items()}
    prompts = [condition_prompt("oracle", 3), condition_prompt("oracle", 1)]
    for controller in (remote, local):
        controller.reset([0, 1])
    for _ in range(3):
        np.testing.assert_allclose(remote.act(batch, prompts), local.act(batch, prompts), atol=1e-6)
    remote.reset([0, 1])  # new episodes: fresh plans on the server too
    local.reset([0, 1])
    np.testing.assert_allclose(remote.act(batch, prompts[::-1]), local.act(batch, prompts[::-1]), atol=1e-6)


def test_drifted_prompt_is_refused(scripted_server, task_env):
    controller = make_controller(f"openpi://127.0.0.1:{scripted_server}")
    obs, _ = task_env.reset(seed=0)
    controller.reset([0])
    with pytest.raises(ValueError, match="matches no trained template"):
        controller.act(obs, ["pick out the cube. the cube is inside drawer layer 2."])


def test_the_learned_controller_served_by_the_cli_plays_the_same_episode(task_env):
    port = free_port()
    command = [str(Path(sys.executable).parent / "sb3-memret"), "serve", "learned", "--host", "127.0.0.1",
               "--port", str(port)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_healthy(port, process=process)
        remote = make_controller(f"openpi://127.0.0.1:{port}")
        prompt = condition_prompt("oracle", 2)
        served = run_episode(task_env, remote, prompt, seed=1_000_002, layer=2)
        in_process = run_episode(task_env, make_controller("learned"), prompt, seed=1_000_002, layer=2)
        assert served == in_process and served.success
    finally:
        process.terminate()
        process.wait(timeout=30)


def test_a_bad_controller_is_one_line():
    from click.testing import CliRunner

    from sb3_memret.cli import main

    result = CliRunner().invoke(main, ["serve", "pi0", "--port", "1"], prog_name="sb3-memret")
    assert result.exit_code == 2 and "unknown controller 'pi0'" in result.output
    assert len(result.output.strip().splitlines()) == 1
