"""GatherAndRecall1-VLA-v0's flash reader against the simulator, frame by frame, over development seeds.

Each episode (seeds ``--seed`` + i; never MIKASA's evaluation seeds) is played by the task's expert with the true
fact in its prompt, the base camera rendering every control step. At every step ``read_flash`` reads the frame and
is scored against MIKASA's state (``flash_active``, ``flash_color``: read here for scoring only): frames read as a
colour while the lamp was white, flash frames read as another colour or missed, whether the fact the writer would
keep (its last reading) names the flash, and the step it was first read at.

    .venv/bin/python lab/2026-11-27-gather-and-recall-reader/gather_and_recall_reader.py [--episodes 20] [--seed 5000]
"""

from __future__ import annotations

import argparse
import time

import torch

from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks.mikasa.gather_and_recall.task import FLASH_COLOURS, GatherAndRecallTask, read_flash


def play(task: GatherAndRecallTask, env, seed: int, replan: int) -> dict:
    obs, info = env.reset(seed=seed)
    frame, = task.frames(env, obs, info, reset=True)
    episode = task.episode(frame)
    prompt = build_prompt(task.instruction(episode), task.oracle_facts(episode), task.prompt_template)
    expert = task.expert()
    expert.reset([seed])
    counts = {"false": 0, "wrong": 0, "missed": 0, "flash_frames": 0}
    last, first_read, success, chunk = None, None, False, None
    for step in range(task.max_control_steps):
        if step % replan == 0:
            chunk = expert.act(obs, [prompt])[0]
        obs, _, terminated, truncated, info = env.step(torch.from_numpy(chunk[step % replan][None]).float())
        success |= bool(info["success"][0])
        read = read_flash(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0])
        truth = FLASH_COLOURS[int(info["flash_color"][0])] if bool(info["flash_active"][0]) else None
        counts["flash_frames"] += truth is not None
        counts["false"] += truth is None and read is not None
        counts["wrong"] += truth is not None and read is not None and read != truth
        counts["missed"] += truth is not None and read is None
        last = read or last
        first_read = step + 1 if first_read is None and read is not None else first_read
        if bool(terminated[0]) or bool(truncated[0]):
            break
    return {**counts, "written_right": last == episode.group, "first_read": first_read, "success": success,
            "steps": step + 1}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=5000, help="first development seed")
    parser.add_argument("--replan", type=int, default=4)
    args = parser.parse_args()
    task = GatherAndRecallTask()
    env = task.make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    start = time.time()
    try:
        results = [play(task, env, args.seed + i, args.replan) for i in range(args.episodes)]
    finally:
        env.close()
    total = {key: sum(r[key] for r in results) for key in ("false", "wrong", "missed", "flash_frames")}
    frames = sum(r["steps"] for r in results)
    first = [r["first_read"] for r in results if r["first_read"] is not None]
    print(f"{len(results)} episodes, {frames} frames ({total['flash_frames']} of the flash): read as a colour while "
          f"white {total['false']}, as another colour {total['wrong']}, missed {total['missed']}; the kept fact "
          f"names the flash in {sum(r['written_right'] for r in results)}/{len(results)}, first read at step "
          f"{min(first, default=None)}-{max(first, default=None)}; expert (true fact) "
          f"success {sum(r['success'] for r in results)}/{len(results)}; {time.time() - start:.0f}s")


if __name__ == "__main__":
    main()
