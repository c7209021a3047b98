"""OpenPIController against a loopback server speaking openpi's msgpack-numpy websocket protocol."""

from __future__ import annotations

import socket
import threading
import time
from typing import Any, Callable

import numpy as np
import pytest

pytest.importorskip("openpi_client", reason="openpi-client is not installed (pip install --no-deps openpi-client)")

import websockets.sync.server  # noqa: E402
from openpi_client import msgpack_numpy  # noqa: E402

from sb3_memret.controllers.openpi import (  # noqa: E402
    OpenPIController,
    PolicyServerError,
    ServerLimits,
    pi05_libero_request,
)
from sb3_memret.tasks.drawer.prompts import TEMPLATE, condition_prompt  # noqa: E402

FAST = ServerLimits(connect_timeout=1.0, infer_timeout=0.3, attempts=2, backoff=0.05)
PI05_KEYS = {"observation/image", "observation/wrist_image", "observation/state", "prompt"}


class LoopbackServer:
    """An openpi-protocol policy server on 127.0.0.1: metadata on connect, then one reply per request.

    ``policy(request, n)`` gets the n-th request of the server's life and returns a reply dict, a
    str (sent as openpi sends a traceback: a text frame, then close 1011), or None to drop the
    connection without answering.
    """

    def __init__(self, policy: Callable[[dict, int], Any], metadata: dict | None = None):
        self.policy, self.metadata = policy, metadata or {}
        self.requests: list[dict] = []
        self.stop = threading.Event()
        self._server = websockets.sync.server.serve(self._handle, "127.0.0.1", 0, compression=None, max_size=None)
        self.port = self._server.socket.getsockname()[1]
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)
        self._thread.start()

    def _handle(self, ws: websockets.sync.server.ServerConnection) -> None:
        ws.send(msgpack_numpy.packb(self.metadata))
        for message in ws:
            request = msgpack_numpy.unpackb(message)
            self.requests.append(request)
            reply = self.policy(request, len(self.requests))
            if reply is None:
                return
            if isinstance(reply, str):
                ws.send(reply)
                ws.close(code=1011, reason="Internal server error. Traceback included in previous frame.")
                return
            ws.send(msgpack_numpy.packb(reply))

    def close(self) -> None:
        self.stop.set()
        self._server.shutdown()
        self._thread.join(timeout=5)


@pytest.fixture
def serve():
    servers = []

    def start(policy, metadata=None) -> LoopbackServer:
        servers.append(LoopbackServer(policy, metadata))
        return servers[-1]

    yield start
    for server in servers:
        server.close()


def chunk_for(request: dict, n: int = 0, horizon: int = 10) -> dict:
    """A reply whose actions encode the request's state, so tests can tell which env it answers."""
    return {"actions": np.tile(request["observation/state"][:1], (horizon, 7)).astype(np.float64)}


def fake_obs(batch: int = 2) -> dict:
    """A rendered DrawerCubeTakeOut-v1 observation (rgb obs mode), built by hand: no renderer needed."""
    rng = np.random.default_rng(0)
    images = lambda: rng.integers(0, 256, size=(batch, 224, 224, 3), dtype=np.uint8)  # noqa: E731
    return {
        "agent": {"eef_state": np.arange(batch * 8, dtype=np.float32).reshape(batch, 8)},
        "extra": {},
        "sensor_data": {"base_camera": {"rgb": images()}, "hand_camera": {"rgb": images()}},
    }


def controller_for(server: LoopbackServer, **kwargs) -> OpenPIController:
    kwargs.setdefault("task_template", TEMPLATE)
    controller = OpenPIController("127.0.0.1", server.port, limits=kwargs.pop("limits", FAST), **kwargs)
    controller.reset(range(2))
    return controller


def test_full_request_response_cycle(serve):
    server = serve(chunk_for)
    controller = controller_for(server)
    obs = fake_obs(2)
    prompts = [condition_prompt("oracle", 2), condition_prompt("none", 1)]
    chunks = controller.act(obs, prompts)

    assert chunks.shape == (2, 10, 7) and chunks.dtype == np.float32
    assert [r["prompt"] for r in server.requests] == prompts  # verbatim, one request per env
    for i, request in enumerate(server.requests):
        assert set(request) == PI05_KEYS | {"sb3_memret/client", "sb3_memret/env", "sb3_memret/episode",
                                            "sb3_memret/seed"}
        assert request["sb3_memret/env"] == request["sb3_memret/seed"] == i  # reset(range(2))
        assert request["sb3_memret/episode"] == i  # the first reset numbers each slot's episode apart
        for key, camera in (("observation/image", "base_camera"), ("observation/wrist_image", "hand_camera")):
            assert request[key].dtype == np.uint8 and request[key].shape == (224, 224, 3)
            np.testing.assert_array_equal(request[key], obs["sensor_data"][camera]["rgb"][i])
        assert request["observation/state"].dtype == np.float32
        np.testing.assert_array_equal(request["observation/state"], obs["agent"]["eef_state"][i])
        np.testing.assert_array_equal(chunks[i], chunk_for(request)["actions"])  # no transform on the way back
    assert controller.spec.action_convention == "pd_ee_delta_pose" and controller.spec.needs_images


def test_one_slot_restarts_alone_and_a_copy_is_a_new_client(serve):
    """``reset_envs`` gives only the named slots new episode numbers (and seeds), so the server restarts only
    their controllers; a copy (a second VecEnv sharing the connection) is a client of its own."""
    import copy

    server = serve(chunk_for)
    controller = controller_for(server)
    prompts = [condition_prompt("oracle", 2), condition_prompt("none", 1)]
    controller.act(fake_obs(2), prompts)
    controller.reset_envs([1], [7])
    controller.act(fake_obs(2), prompts)
    before, after = server.requests[:2], server.requests[2:]
    assert after[0]["sb3_memret/episode"] == before[0]["sb3_memret/episode"] and after[0]["sb3_memret/seed"] == 0
    assert after[1]["sb3_memret/episode"] not in {r["sb3_memret/episode"] for r in before}
    assert after[1]["sb3_memret/seed"] == 7
    with pytest.raises(ValueError, match=r"env ids \[2\] are outside the batch of 2"):
        controller.reset_envs([2], [0])
    twin = copy.copy(controller)
    twin.reset(range(2))
    twin.act(fake_obs(2), prompts)
    assert server.requests[-1]["sb3_memret/client"] != before[0]["sb3_memret/client"]


def test_a_few_decisions_on_rendered_camera_images(serve, rgb_task_env):
    """The real task with both cameras rendered on the CPU: what reaches the server is the rendered
    frames, unchanged, at every decision, and the server's actions drive the robot."""
    from sb3_memret.physics.chunks import execute_chunk

    server = serve(lambda request, n: {"actions": np.tile([0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], (10, 1))})
    controller = OpenPIController("127.0.0.1", server.port, limits=FAST, task_template=TEMPLATE)
    controller.check_env(rgb_task_env)
    obs, _ = rgb_task_env.reset(seed=5, options={"target_layer": 3})
    controller.reset([5])
    start = obs["agent"]["eef_state"][0, :3].clone()
    sent = []
    for _ in range(3):
        sent.append({k: obs["sensor_data"][cam]["rgb"][0].numpy().copy()
                     for k, cam in (("observation/image", "base_camera"), ("observation/wrist_image", "hand_camera"))})
        obs = execute_chunk(rgb_task_env, controller.act(obs, [condition_prompt("oracle", 3)])[0][:8]).obs
    assert len(server.requests) == 3
    for request, images in zip(server.requests, sent):
        for key, image in images.items():
            np.testing.assert_array_equal(request[key], image)
            assert image.std() > 10  # a rendered scene, not a blank frame
    assert not np.array_equal(server.requests[0]["observation/wrist_image"], server.requests[2]["observation/wrist_image"])
    assert float((obs["agent"]["eef_state"][0, :3] - start).norm()) > 0.02  # the server's actions moved the hand


def test_chunk_len_comes_from_server_metadata(serve):
    server = serve(lambda r, n: chunk_for(r, n, horizon=15), metadata={"action_horizon": 15})
    controller = controller_for(server)
    assert controller.spec.chunk_len == 15
    assert controller.act(fake_obs(2), ["pick out the cube."] * 2).shape == (2, 15, 7)


def test_server_error_is_raised_with_its_traceback_and_not_retried(serve):
    server = serve(lambda r, n: "Traceback (most recent call last):\n  KeyError: 'observation/state'")
    controller = controller_for(server)
    with pytest.raises(PolicyServerError, match=r"(?s)ws://127\.0\.0\.1:\d+ failed.*KeyError: 'observation/state'"):
        controller.act(fake_obs(2), ["pick out the cube."] * 2)
    assert len(server.requests) == 1


@pytest.mark.parametrize("shape", [(10, 8), (10, 6), (5, 7), (7,)])
def test_actions_of_another_convention_are_refused(serve, shape):
    server = serve(lambda r, n: {"actions": np.zeros(shape)})
    with pytest.raises(PolicyServerError, match=r"expected \(10, 7\).*never transformed"):
        controller_for(server).act(fake_obs(2), ["pick out the cube."] * 2)


def test_reply_without_actions_is_refused(serve):
    server = serve(lambda r, n: {"action": np.zeros((10, 7))})
    with pytest.raises(PolicyServerError, match="without 'actions'"):
        controller_for(server).act(fake_obs(2), ["pick out the cube."] * 2)


def test_slow_server_times_out_within_a_bound(serve):
    def slow(request, n):
        server.stop.wait(5.0)
        return chunk_for(request)

    server = serve(slow)
    controller = controller_for(server)
    start = time.monotonic()
    with pytest.raises(TimeoutError, match=r"ws://127\.0\.0\.1:\d+: infer failed 2 times \(no reply within 0\.3 s\)"):
        controller.act(fake_obs(2), ["pick out the cube."] * 2)
    assert time.monotonic() - start < 3.0  # 2 x (0.3 s wait + 0.5 s close) + backoff
    assert len(server.requests) == 2  # retried once on a fresh connection, then gave up


def test_dropped_connection_is_retried_on_a_fresh_one(serve):
    server = serve(lambda r, n: None if n == 1 else chunk_for(r))
    chunks = controller_for(server).act(fake_obs(2), ["pick out the cube."] * 2)
    assert chunks.shape == (2, 10, 7)
    assert len(server.requests) == 3  # env 0 twice (first reply lost), env 1 once


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_server_down_gets_bounded_retries_then_an_error():
    port = _free_port()
    start = time.monotonic()
    with pytest.raises(ConnectionError, match=rf"ws://127\.0\.0\.1:{port}: connect failed 3 times"):
        OpenPIController("127.0.0.1", port, limits=ServerLimits(connect_timeout=0.5, attempts=3, backoff=0.05))
    assert time.monotonic() - start < 2.0


def test_server_that_never_answers_the_handshake_times_out():
    """A listening socket that accepts and stays silent: the connect wait is bounded too."""
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        port = listener.getsockname()[1]
        start = time.monotonic()
        with pytest.raises(TimeoutError, match=rf"ws://127\.0\.0\.1:{port}: connect failed 2 times"):
            OpenPIController("127.0.0.1", port, limits=ServerLimits(connect_timeout=0.3, attempts=2, backoff=0.05))
        assert time.monotonic() - start < 2.0


@pytest.mark.parametrize("prompt", [
    "pick out the cube. The cube is in drawer layer 2.",  # capitalised
    "pick out the cube.  the cube is in drawer layer 2.",  # double space
    "pick out the cube. the cube is in the drawer layer 2.",  # drifted wording
    "pick out the cube. the cube is in drawer layer 2",  # no full stop
])
def test_drifted_prompt_is_refused_before_reaching_the_server(serve, prompt):
    server = serve(chunk_for)
    controller = controller_for(server)
    with pytest.raises(ValueError, match="prompt"):
        controller.act(fake_obs(2), ["pick out the cube.", prompt])
    assert server.requests == []


def test_missing_images_are_refused_with_how_to_render(serve):
    server = serve(chunk_for)
    obs = fake_obs(2)
    del obs["sensor_data"]["hand_camera"]
    with pytest.raises(ValueError, match=r"no hand_camera image.*render_backend"):
        controller_for(server).act(obs, ["pick out the cube."] * 2)
    assert server.requests == []


def test_images_of_the_wrong_size_are_refused():
    obs = fake_obs(1)
    obs["sensor_data"]["base_camera"]["rgb"] = np.zeros((1, 256, 256, 3), np.uint8)
    with pytest.raises(ValueError, match=r"base_camera image of env 0 is uint8\(256, 256, 3\)"):
        pi05_libero_request(obs, 0, "pick out the cube.")


class _Env:
    def __init__(self, control_mode: str, obs_mode: str):
        self.control_mode, self.obs_mode = control_mode, obs_mode


def test_env_without_cameras_or_with_another_controller_is_refused(serve):
    controller = controller_for(serve(chunk_for))
    controller.check_env(_Env("pd_ee_delta_pose", "rgb"))
    with pytest.raises(ValueError, match=r"needs camera images.*'state_dict'.*lavapipe"):
        controller.check_env(_Env("pd_ee_delta_pose", "state_dict"))
    with pytest.raises(ValueError, match=r"emits 'pd_ee_delta_pose' actions.*'pd_joint_delta_pos'"):
        controller.check_env(_Env("pd_joint_delta_pos", "rgb"))


def test_batch_size_must_match_reset(serve):
    controller = controller_for(serve(chunk_for))
    controller.reset([0])
    with pytest.raises(RuntimeError, match="reset\\(\\) was called for 1 envs but act\\(\\) got 2"):
        controller.act(fake_obs(2), ["pick out the cube."] * 2)


@pytest.mark.filterwarnings("ignore:connect\\(\\) must be used as a context manager:DeprecationWarning")  # openpi's client
def test_loopback_server_speaks_openpis_protocol(serve):
    """openpi's own client talks to the loopback server, so the tests exercise the real protocol."""
    from openpi_client.websocket_client_policy import WebsocketClientPolicy

    server = serve(chunk_for, metadata={"served": "pi05_libero"})
    client = WebsocketClientPolicy("127.0.0.1", server.port)
    assert client.get_server_metadata() == {"served": "pi05_libero"}
    reply = client.infer(pi05_libero_request(fake_obs(1), 0, "pick out the cube."))
    assert reply["actions"].shape == (10, 7)
