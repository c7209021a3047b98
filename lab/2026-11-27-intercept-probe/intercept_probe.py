"""Probe MIKASA-Robo-VLA's Intercept and InterceptGrab tasks: the speed reader's error and the catch expert's success.

For each task, ``--episodes`` episodes at development seeds (``--seed`` + i; never MIKASA's evaluation seeds) per
prompt condition. ``written``: the base camera renders every control step, the task's writer reads the ball's
speed from it, and the expert's prompt carries the fact from the replan after it was written (as ``rollout
--condition written`` does); the probe scores the written speed against the truth (5/7 of MIKASA's launch
velocity, read from the simulator for scoring only) and says at which step it was written. ``oracle``, ``none``
and ``wrong`` prompts do not depend on the camera, so those episodes run without rendering. Success is MIKASA's
success-once over the 60 steps; the expert replans every ``--replan`` steps.

    .venv/bin/python lab/2026-11-27-intercept-probe/intercept_probe.py [--tasks InterceptSlow-VLA-v0] [--episodes 20] [--conditions written]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.intercept.task import VARIANTS, InterceptTask, motion_fact, parse_value

CONDITIONS = ("written", "oracle", "none", "wrong")


def play(task: InterceptTask, env, seed: int, condition: str, replan: int) -> dict:
    """One episode; the written condition's fact (if any), the step it was written at and its error (cm/s)."""
    obs, info = env.reset(seed=seed)
    frame, = task.frames(env, obs, info, reset=True)
    episode = task.episode(frame)
    truth = parse_value(episode.true_facts[0][1])
    fixed = {"oracle": task.oracle_facts, "none": lambda _: [], "wrong": task.wrong_facts}
    facts = [] if condition == "written" else fixed[condition](episode)
    writer, expert = task.writer(), task.expert()
    if condition == "written":
        frame.percepts = [task.perceive(env, obs)]
        writer.read(frame)
    expert.reset([seed])
    result = {"success": False, "written_at": None, "error_cm_s": None, "truth_cm_s": round(truth.speed * 100)}
    chunk = None
    for step in range(task.max_control_steps):
        if step % replan == 0:
            chunk = expert.act(obs, [build_prompt(task.instruction(episode), facts, task.prompt_template)])[0]
        obs, _, _, _, info = env.step(torch.from_numpy(chunk[step % replan][None]).float())
        result["success"] |= bool(info["success"][0])
        if condition == "written" and not facts:
            frame, = task.frames(env, obs, info)
            frame.steps, frame.percepts = 1, [task.perceive(env, obs)]
            for _, predicates in writer.read(frame):
                stated = parse_value(next(iter(predicates.values())))
                facts = [motion_fact(stated)]
                result["written_at"] = step + 1
                result["error_cm_s"] = round(stated.speed * 100) - round(truth.speed * 100)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=5000, help="first development seed")
    parser.add_argument("--conditions", nargs="+", default=list(CONDITIONS), choices=CONDITIONS)
    parser.add_argument("--replan", type=int, default=4)
    args = parser.parse_args()
    for name in args.tasks:
        task = make_task(name)
        for condition in args.conditions:
            start = time.time()
            env = task.make_env(obs_mode="rgb" if condition == "written" else "state_dict", render_backend="cpu",
                                sim_backend="cpu", robot_uids="panda")
            try:
                results = [play(task, env, args.seed + i, condition, args.replan) for i in range(args.episodes)]
            finally:
                env.close()
            wins = sum(r["success"] for r in results)
            line = f"{name} {condition}: success {wins}/{len(results)}"
            failed = [(args.seed + i, r["truth_cm_s"]) for i, r in enumerate(results) if not r["success"]]
            if condition == "written":
                errors = [r["error_cm_s"] for r in results if r["error_cm_s"] is not None]
                steps = [r["written_at"] for r in results if r["written_at"] is not None]
                line += (f"; written in {len(errors)}/{len(results)} episodes, at step {min(steps)}-{max(steps)} "
                         f"(median {np.median(steps):.0f}); error (cm/s) mean {np.mean(errors):+.2f}, "
                         f"max |error| {max(map(abs, errors))}") if errors else "; never written"
            print(f"{line}; failed (seed, cm/s): {failed}; {time.time() - start:.0f}s", flush=True)


if __name__ == "__main__":
    main()
