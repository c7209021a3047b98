"""Play the scripted expert on the oracle's facts (and, for TraceShapeSeq, MIKASA's progress) at development seeds and
print each episode's phases: for TraceShapeSeq the lamp's green, each path's closure and the press; for
GatherAndRecall each cube's arrival on the disc, any placed cube knocked off, the flash and the press.

    .venv/bin/python lab/2026-12-05-oracle-misses-on-long-trace-and-gather/phase_probe.py \
        --task TraceShapeSeqMedium-VLA-v0 --seeds 5000 5010
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks import make_task


def trace_events(env, info, last: dict) -> list[str]:
    """TraceShapeSeq: the green lamp, each closure (with the active path's radius), a press."""
    base, out = env.unwrapped, []
    closed = int(as_numpy(base.shape_closed)[0].sum())
    if bool(as_numpy(info["action_mask"])[0]) and not last.get("green"):
        last["green"] = True
        out.append("green")
    if closed != last.get("closed", 0):
        last["closed"] = closed
        out.append(f"closed {closed}")
    if bool(as_numpy(info["submitted"])[0]):
        out.append("press")
    return out


def gather_events(env, info, last: dict) -> list[str]:
    """GatherAndRecall: the count ever on the disc, cubes now on it, the flash, a press."""
    base, out = env.unwrapped, []
    ever = int(as_numpy(info["n_on_disc"])[0])
    if ever != last.get("ever", 0):
        last["ever"] = ever
        out.append(f"on {ever}")
    if bool(as_numpy(info["flash_active"])[0]) and not last.get("flash"):
        last["flash"] = True
        out.append("flash")
    pressed = int(as_numpy(base.pressed_button)[0])
    if pressed >= 0 and not last.get("pressed"):
        last["pressed"] = True
        out.append(f"press {pressed} (flash {int(as_numpy(base.flash_color)[0])})")
    return out


def summary(task, env, info) -> str:
    """What stood at the end: the paths closed and the active one's checkpoints, or the cubes off the disc."""
    base = env.unwrapped
    if hasattr(base, "shape_closed"):
        n = int(as_numpy(base.sequence_len)[0])
        shapes = as_numpy(base.shape_sequence)[0][:n].tolist()
        visited = float(as_numpy(info["active_visit_fraction"])[0])
        return f"paths {shapes} closed {int(as_numpy(base.shape_closed)[0].sum())}/{n}, active visited {visited:.2f}"
    disc = as_numpy(base.disc.pose.p)[0]
    cubes = np.array([as_numpy(c.pose.p)[0] for c in base.cubes])
    off = np.linalg.norm(cubes[:, :2] - disc[:2], axis=1)
    return f"cubes' distance to the disc's centre (cm): {np.round(100 * off, 1).tolist()}, z {np.round(100 * cubes[:, 2], 1).tolist()}"


def episode(task, env, expert, seed: int, replan: int) -> str:
    """One oracle episode, its events by step and its end."""
    obs, info = env.reset(seed=seed)
    (frame,) = task.frames(env, obs, info, reset=True)
    ep = task.episode(frame)
    expert.reset([seed])
    events, last, success, t0 = [], {}, False, time.time()
    track = trace_events if hasattr(env.unwrapped, "shape_closed") else gather_events
    for step in range(task.max_control_steps):
        if step % replan == 0:
            (frame,) = task.frames(env, obs, info)
            facts = task.oracle_facts(ep) + (task.progress_facts(frame) if hasattr(task, "progress_facts") else [])
            chunk = expert.act(obs, [build_prompt(task.instruction(ep), facts, task.prompt_template)])[0]
        obs, _, terminated, truncated, info = env.step(torch.from_numpy(chunk[step % replan][None]).float())
        success |= bool(as_numpy(info["success"])[0])
        events += [f"{e}@{step + 1}" for e in track(env, info, last)]
        if bool(terminated[0]) or bool(truncated[0]):
            break
    return (f"{seed}: success {success} steps {step + 1} ({time.time() - t0:.0f}s) | {' '.join(events)} | "
            f"{summary(task, env, info)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="TraceShapeSeqMedium-VLA-v0")
    parser.add_argument("--seeds", type=int, nargs=2, default=[5000, 5010], metavar=("FIRST", "END"))
    args = parser.parse_args()
    task = make_task(args.task)
    env = task.make_env(obs_mode="state_dict", render_backend="cpu", robot_uids="panda")
    expert = task.expert()
    replan = task.replan_interval(None, expert.spec.chunk_len)
    for seed in range(*args.seeds):
        print(episode(task, env, expert, seed, replan), flush=True)


if __name__ == "__main__":
    main()
