"""Probe the TraceShape / TraceShapeSeq tasks at development seeds: the path writer's reading against MIKASA's
waypoints (``--writer``), or the scripted expert prompted with the oracle's facts (and, for the sequence, MIKASA's own
progress), episode by episode: success, whether the cube was lifted and dropped, checkpoints visited.

    .venv/bin/python lab/2026-12-05-timed-transfer-and-trace-shape-at-development-seeds/trace_probe.py \
        --task TraceShapeHard-VLA-v0 --seeds 5006 5046 [--writer]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.base import EnvFrame


def writer_error(task, env, seed: int) -> str:
    """The writer's fact after the demonstration, beside the truth, and the per-frame sighting error."""
    obs, info = env.reset(seed=seed)
    (frame,) = task.frames(env, obs, info, reset=True)
    truth = task.oracle_facts(task.episode(frame))
    writer = task.writer()
    frame.percepts = [task.perceive(env, obs)]
    written, errors = writer.read(frame), []
    for _ in range(task.perception_window(env) or 80):
        obs, *_ = env.step(np.zeros((1, 7), np.float32))
        percept = task.perceive(env, obs)
        red = as_numpy(env.unwrapped.red_cube.pose.p)[0]
        if percept.red_cube is not None and red[2] < 1:
            errors.append(np.hypot(percept.red_cube[0] - red[0], percept.red_cube[1] - red[1]))
        written += writer.read(EnvFrame({}, {}, None, False, steps=1, percepts=[percept]))
    return (f"{seed} truth {truth} | written {[p for _, p in written]} | sighting error mean "
            f"{100 * np.mean(errors):.2f} cm, max {100 * np.max(errors):.2f} cm")


def oracle_episode(task, env, expert, seed: int) -> str:
    """One episode of the expert on the oracle's facts (and MIKASA's progress), with what became of the cube."""
    obs, info = env.reset(seed=seed)
    (frame,) = task.frames(env, obs, info, reset=True)
    episode = task.episode(frame)
    expert.reset([seed])
    lifted = dropped = None
    for step in range(task.max_control_steps):
        if step % 4 == 0:
            (frame,) = task.frames(env, obs, info)
            facts = task.oracle_facts(episode) + task.progress_facts(frame)
            chunk = expert.act(obs, [build_prompt(task.instruction(episode), facts, task.prompt_template)])[0]
        obs, _, terminated, truncated, info = env.step(torch.from_numpy(chunk[step % 4][None]).float())
        z = float(as_numpy(env.unwrapped.green_cube.pose.p)[0][2])
        lifted = step if lifted is None and z > 0.035 else lifted
        dropped = step if lifted is not None and dropped is None and z < 0.025 else dropped
        if bool(terminated[0]) or bool(truncated[0]):
            break
    return (f"{seed} {episode.group}: success {bool(info['success'][0])} at step {step}, lifted at {lifted}, "
            f"dropped at {dropped}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="TraceShapeHard-VLA-v0")
    parser.add_argument("--seeds", type=int, nargs=2, default=[5006, 5026], metavar=("FIRST", "END"))
    parser.add_argument("--writer", action="store_true", help="the writer's reading instead of the expert")
    args = parser.parse_args()
    task = make_task(args.task)
    env = task.make_env(obs_mode="rgb" if args.writer else "state_dict", render_backend="cpu", robot_uids="panda")
    expert = task.expert()
    for seed in range(*args.seeds):
        print(writer_error(task, env, seed) if args.writer else oracle_episode(task, env, expert, seed), flush=True)


if __name__ == "__main__":
    main()
