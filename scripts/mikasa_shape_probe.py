"""Probe MIKASA-Robo-VLA's RememberShape3 task: the scripted expert's success and the cue reader's accuracy.

As ``mikasa_probe.py`` does for RememberColor: ``--episodes`` episodes at MIKASA's evaluation seeds
(4242424242 + i) per prompt condition: ``oracle`` (instruction + the true cue shape; read from the
env's ``oracle_info`` only to build this prompt), ``none`` (the bare instruction) and ``wrong`` (the
next shape). Success is MIKASA's success-once over the 25-step episode. The expert replans every
``--replan`` control steps. At every step the base-camera frame goes through ``read_cue_shape``,
scored against the episode's phase (cue / delay / manipulation).

    .venv/bin/python scripts/mikasa_shape_probe.py [--episodes 50] [--conditions oracle none wrong]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mikasa_probe import MIKASA_SEED, CONDITIONS, CueStats, phase_of, report_cues  # noqa: E402

TASK = "RememberShape3-VLA-v0"


def make_env(obs_mode: str = "rgb"):
    """The task's env as the project runs it (CPU renderer, MIKASA's no-op wrapper, the controller's view),
    with the base camera only (``robot_uids="panda"``): the reader's camera."""
    from sb3_memret.tasks.mikasa.remember_shape import RememberShapeTask

    return RememberShapeTask(TASK).make_env(obs_mode=obs_mode, sim_backend="cpu", robot_uids="panda")


def run_episode(env, controller, seed: int, condition: str, replan: int, stats: CueStats) -> tuple[bool, int, float]:
    """One episode; returns (success once, control steps, seconds spent in env.step)."""
    from sb3_memret.tasks.mikasa.remember_shape import shape_prompt
    from sb3_memret.tasks.mikasa.shape_perception import SHAPE_NAMES, read_cue_shape

    obs, info = env.reset(seed=seed)
    base = env.unwrapped
    n = len(base.shape_actors)
    true = int(info["oracle_info"][0])  # metrics and the oracle prompt only
    shape = {"oracle": SHAPE_NAMES[true], "wrong": SHAPE_NAMES[(true + 1) % n], "none": None}[condition]
    prompt = shape_prompt(shape)
    controller.reset([seed])
    success, steps, env_seconds, chunk, done = False, 0, 0.0, None, False
    while True:
        elapsed = int(info["elapsed_steps"][0])
        t0 = time.perf_counter()
        reading = read_cue_shape(obs["sensor_data"]["base_camera"]["rgb"][0].cpu().numpy(), n)
        stats.seconds += time.perf_counter() - t0
        phase = phase_of(base, elapsed)
        stats.frames[phase] += 1
        if phase == "cue":
            stats.confusion[(SHAPE_NAMES[true], reading)] += 1
        elif reading is not None:
            stats.false_readings[phase] += 1
        if done:
            break
        if steps % replan == 0:
            chunk = controller.act(obs, [prompt])[0]
        t0 = time.perf_counter()
        obs, _, terminated, truncated, info = env.step(torch.from_numpy(chunk[steps % replan][None]).float())
        env_seconds += time.perf_counter() - t0
        steps += 1
        success |= bool(info["success"][0])
        done = bool(terminated[0]) or bool(truncated[0])
    return success, steps, env_seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--conditions", nargs="+", default=list(CONDITIONS), choices=CONDITIONS)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--replan", type=int, default=4, help="control steps executed of each chunk")
    args = parser.parse_args()

    from sb3_memret.tasks.mikasa.remember_shape import shape_expert

    env = make_env()
    controller = shape_expert()
    controller.check_env(env)
    stats = CueStats()
    for condition in args.conditions:
        wins, steps, seconds, t0 = 0, 0, 0.0, time.perf_counter()
        for i in range(args.episodes):
            ok, n, s = run_episode(env, controller, MIKASA_SEED + i, condition, args.replan, stats)
            wins, steps, seconds = wins + ok, steps + n, seconds + s
        wall = time.perf_counter() - t0
        print(f"{TASK} {condition:6s} success_once {wins}/{args.episodes} = {wins / args.episodes:.0%}  "
              f"env steps/s {steps / seconds:.1f} (env.step only), {steps / wall:.1f} (with reset, expert, "
              f"cue reading)", flush=True)
    report_cues(f"{TASK} cue reading (the episodes above)", stats)
    env.close()


if __name__ == "__main__":
    main()
