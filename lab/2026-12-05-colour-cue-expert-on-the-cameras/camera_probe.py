"""Play colour-cue episodes with the camera expert (``scripted-camera``) through MIKASA's harness, as a
``benchmark mikasa --workers 1`` worker plays them (development seeds, in order, one env), and print every
``--every``-th decision: the prompt's progress facts, the TCP, its estimated step, and what MIKASA counted (touches,
press, static), read outside the agent's turn.

    .venv/bin/python lab/2026-12-05-colour-cue-expert-on-the-cameras/camera_probe.py \
        --task SeqOfColors3-VLA-v0 --condition written --episodes 1 --show 5000
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_memret.benchmark.guard import benchmark_reads
from sb3_memret.benchmark.runner import Protocol, Unit, _Worker
from sb3_memret.controllers.base import as_numpy


def traced(agent, log: list[str]) -> None:
    """Wrap the camera expert's ``_act`` so that every decision appends a line to ``log``."""
    expert = agent.controller
    act = expert._act
    placed_errors: dict[str, float] = {}

    def logged(obs, prompts, parsed):
        chunk = act(obs, prompts, parsed)
        tcp = as_numpy(obs["extra"]["tcp_pose"])[0, :3]
        with benchmark_reads("the probe's look at MIKASA's counters"):
            base = agent.env.unwrapped
            touched = as_numpy(base.touched_cubes_idx).reshape(-1).tolist() if hasattr(base, "touched_cubes_idx") \
                else np.flatnonzero(as_numpy(base.touched_cubes).reshape(-1)).tolist()
            presses = int(as_numpy(base.button_press_count).reshape(-1)[0])
            static = bool(as_numpy(base.agent.is_static(0.2)).reshape(-1)[0])
            truth = {c: as_numpy(base.cubes[i].pose.p).reshape(-1)[:2] for i, c in enumerate(expert.vocabulary)}
        places = expert.layouts[0].places
        if places and not placed_errors:  # the layout's error, once, when it is first placed
            placed_errors.update({c: round(100 * float(np.linalg.norm(p - truth[c])), 2) for c, p in places.items()})
            log.append(f"layout error (cm) {placed_errors}")
        facts = [f.template.split(" ")[1] + ":" + dict(f.fields).get("touched", "") for f in parsed[0].facts
                 if "touched" in f.template or "pressed" in f.template]
        log.append(f"tcp {np.round(tcp, 3)} facts {facts} mikasa touched {touched} presses {presses} "
                   f"static {static} placed {len(expert.layouts[0].places)} chunk0 {np.round(chunk[0, 0, :3], 2)}")
        return chunk
    expert._act = logged


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="SeqOfColors3-VLA-v0")
    parser.add_argument("--condition", default="written")
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--show", type=int, nargs="*", default=[])
    parser.add_argument("--every", type=int, default=1)
    args = parser.parse_args()
    protocol = Protocol(seed_set="dev", episodes=args.episodes, controller="scripted-camera")
    worker = _Worker(protocol, None)
    for seed in protocol.seeds():
        agent = worker.agent(args.task, args.condition)
        log: list[str] = []
        if seed in args.show:
            traced(agent, log)
        record = worker.play(Unit(args.task, args.condition, seed))
        print(seed, record.get("success"), record.get("steps"), record.get("error", ""), flush=True)
        for i, line in enumerate(log):
            if i % args.every == 0:
                print(f"  d{i} step {i * agent.replan_every}: {line}")
        agent.controller.__dict__.pop("_act", None)


if __name__ == "__main__":
    main()
