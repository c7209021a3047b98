"""How fast ``sb3-memret serve`` refuses what it must not serve, beside one valid request: a 100,000-character prompt
(refused by its length before the controller parses it; parsing it took seconds before the limit) and oversize
messages (closed by websockets with 1009, unread). Serves the scripted expert on the loopback in this process, with
hand-built state-only requests (no simulator). Prints the median milliseconds of each over ``--repeats``.

Usage: ``python scripts/bench_serve_refusals.py [--repeats 20] [--unguarded]``; ``--unguarded`` also times the
controller parsing the long prompt itself, what each such request cost before the limit.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import socket
import threading
import time
import urllib.request
from typing import Callable

import numpy as np
import websockets.exceptions
import websockets.sync.client
from openpi_client import msgpack_numpy

from sb3_memret.stage1.serve import MAX_PROMPT_CHARS, MAX_REQUEST_BYTES, ControllerPolicy, GuardedPolicyServer
from sb3_memret.tasks.drawer.prompts import condition_prompt

LONG_PROMPT = "x" * 100_000  # no full stop: splitting it into sentences takes seconds
OVERSIZE = {"largest valid request + 1 byte": MAX_REQUEST_BYTES + 1, "16 MiB": 16 << 20}


def request(prompt: str) -> dict:
    """A valid state-only request but for ``prompt``."""
    return {"observation/state": np.zeros(8, np.float32), "observation/drawer_opening": np.zeros(3, np.float32),
            "observation/target_detection": np.zeros(8, np.float32), "prompt": prompt}


def start_server(policy: ControllerPolicy) -> str:
    """The serve command's server around ``policy`` on a free loopback port, in a daemon thread; its address."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = GuardedPolicyServer(policy, "127.0.0.1", port)
    logging.getLogger("websockets.server").setLevel(logging.CRITICAL)  # each refusal's traceback, expected here
    threading.Thread(target=lambda: asyncio.run(server.run()), daemon=True).start()
    for _ in range(300):
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=1).close()
            return f"ws://127.0.0.1:{port}"
        except OSError:
            time.sleep(0.1)
    raise TimeoutError(f"the server on port {port} never answered /healthz")


def reply_ms(uri: str, message: bytes, expect: Callable[[bytes | str | None], bool]) -> float:
    """Milliseconds from sending ``message`` on a fresh connection to the server's answer (``None``: it closed the
    connection), which must satisfy ``expect``."""
    with websockets.sync.client.connect(uri, compression=None, max_size=None) as ws:
        ws.recv(timeout=60)  # metadata
        started = time.perf_counter()
        try:
            ws.send(message)
            answer = ws.recv(timeout=60)
        except websockets.exceptions.ConnectionClosed as closed:
            if closed.rcvd is None or closed.rcvd.code != 1009:
                raise
            answer = None
        elapsed = 1000 * (time.perf_counter() - started)
    if not expect(answer):
        raise RuntimeError(f"unexpected answer: {str(answer)[-300:]}")
    return elapsed


def median(times: list[float]) -> float:
    return sorted(times)[len(times) // 2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--unguarded", action="store_true", help="also time the controller parsing the long prompt")
    args = parser.parse_args()
    policy = ControllerPolicy("scripted", "drawer")
    uri = start_server(policy)
    valid = msgpack_numpy.packb(request(condition_prompt("oracle", 1)))
    long_prompt = msgpack_numpy.packb(request(LONG_PROMPT))
    rows = {"one valid request (baseline)": (valid, lambda a: isinstance(a, bytes)),
            f"a {len(LONG_PROMPT):,}-character prompt (limit {MAX_PROMPT_CHARS:,})":
                (long_prompt, lambda a: isinstance(a, str) and f"at most {MAX_PROMPT_CHARS} are accepted" in a)}
    rows |= {f"an oversize message: {name} ({size:,} bytes)": (bytes(size), lambda a: a is None)
             for name, size in OVERSIZE.items()}
    print(f"sb3-memret serve scripted on {uri}, max message {MAX_REQUEST_BYTES:,} bytes; median of {args.repeats}")
    for name, (message, expect) in rows.items():
        print(f"{name}: {median([reply_ms(uri, message, expect) for _ in range(args.repeats)]):.2f} ms")
    if args.unguarded:
        controller, obs = policy._controller_for({}), policy._observation(request(LONG_PROMPT))
        started = time.perf_counter()
        try:
            controller.act(obs, [LONG_PROMPT])
        except ValueError:
            print(f"the controller parsing that prompt (before the limit): {time.perf_counter() - started:.2f} s")


if __name__ == "__main__":
    main()
