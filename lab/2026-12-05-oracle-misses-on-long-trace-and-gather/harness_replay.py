"""Replay a benchmark worker's run of one task through MIKASA's harness (the oracle condition, development seeds, in
order, in one env as ``benchmark mikasa --workers 1`` plays them) and print, for the chosen seeds, every
``--every``-th decision: the TCP, the detected objects, the fingers' gap and the expert's goal. Episodes in one env
are not independent (the physics carries state across resets), so a failure is replayed with its predecessors.

    .venv/bin/python lab/2026-12-05-oracle-misses-on-long-trace-and-gather/harness_replay.py \
        --task TraceShapeSeqMedium-VLA-v0 --episodes 6 --show 5005
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_memret.benchmark.runner import Protocol, Unit, _Worker
from sb3_memret.controllers.base import as_numpy


def traced(expert, log: list[str]) -> None:
    """Wrap ``expert._act`` (and its goal choice) so that every decision appends a line to ``log``."""
    act, goal_of = expert._act, {}
    for name in ("_goal", "_submit"):
        if hasattr(expert, name):
            inner = getattr(expert, name)

            def wrapped(*a, _inner=inner, **k):
                goal_of["last"] = _inner(*a, **k)
                return goal_of["last"]
            setattr(expert, name, wrapped)

    def logged(obs, prompts, parsed):
        chunk = act(obs, prompts, parsed)
        extra = obs["extra"]
        tcp = as_numpy(extra["tcp_pose"])[0, :3]
        cubes = as_numpy(extra["cube_positions"])[0]
        gap = float(as_numpy(obs["agent"]["qpos"])[0, 7:9].sum())
        g = goal_of.get("last")
        log.append(f"tcp {np.round(tcp, 3)} cubes {np.round(cubes, 3).tolist()} gap {gap:.3f} "
                   f"goal {None if g is None else (g.mode, np.round(np.asarray(g.point), 3).tolist())}")
        return chunk
    expert._act = logged


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="TraceShapeSeqMedium-VLA-v0")
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--show", type=int, nargs="*", default=[])
    parser.add_argument("--every", type=int, default=2)
    args = parser.parse_args()
    protocol = Protocol(episodes=args.episodes)
    worker = _Worker(protocol, None)
    for seed in protocol.seeds():
        agent = worker.agent(args.task, "oracle")
        log: list[str] = []
        if seed in args.show:
            traced(agent.controller, log)
        record = worker.play(Unit(args.task, "oracle", seed))
        print(seed, record.get("success"), record.get("steps"), record.get("error", ""), flush=True)
        for i, line in enumerate(log):
            if i % args.every == 0:
                print(f"  d{i} step {i * agent.replan_every}: {line}")
        agent.controller.__dict__.pop("_act", None)


if __name__ == "__main__":
    main()
