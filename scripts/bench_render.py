"""Camera rendering cost: decisions/s on DrawerCubeTakeOut-v1 with both 224x224 cameras, rendering
every control step against rendering only at decisions (``execute_chunk``), in the same run.

    python scripts/bench_render.py [--decisions 12] [--replan-every 8] [--render-backend cpu] [--save-images DIR]

A frozen controller reads images only when it is called, once per ``replan_every`` control steps,
so the frames of the steps in between are never looked at. The scripted controller drives both
arms of the comparison (it reads state only), so the controller's cost is the same in both.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
from sb3_memret.tasks.drawer.prompts import condition_prompt
from sb3_memret.physics.chunks import execute_chunk
from sb3_memret.rollout import make_task_env


def every_step(env, actions: np.ndarray) -> tuple[dict, bool]:
    """The plain loop: each env.step renders both cameras. Returns (obs, episode ended)."""
    for action in actions:
        obs, _, terminated, truncated, _ = env.step(action)
        if bool(terminated) or bool(truncated):
            return obs, True
    return obs, False


def at_decisions(env, actions: np.ndarray) -> tuple[dict, bool]:
    outcome = execute_chunk(env, actions)
    return outcome.obs, outcome.terminated or outcome.truncated


def decisions_per_second(env, controller, step_chunk, decisions: int, replan_every: int, seed: int) -> float:
    """Decisions/s over ``decisions`` decisions of oracle episodes (reset time left out)."""
    prompt = condition_prompt("oracle", 2)
    done, seconds = 0, 0.0
    while done < decisions:
        obs, _ = env.reset(seed=seed + done, options={"target_layer": 2})
        controller.reset([seed + done])
        start = time.perf_counter()
        ended = False
        while done < decisions and not ended:
            obs, ended = step_chunk(env, controller.act(obs, [prompt])[0][:replan_every])
            done += 1
        seconds += time.perf_counter() - start
    return decisions / seconds


def save_images(env, folder: Path) -> None:
    """Both cameras with every drawer closed, then with the cube's drawer (layer 2) pulled open."""
    import torch
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    task = env.unwrapped
    for state, opening in (("closed", 0.0), ("open", 0.25)):
        env.reset(seed=0, options={"target_layer": 2})
        task.cabinet.set_qpos(torch.tensor([[0.0, opening, 0.0]]))
        obs = task.get_obs()
        for camera in ("base_camera", "hand_camera"):
            Image.fromarray(obs["sensor_data"][camera]["rgb"][0].cpu().numpy()).save(folder / f"{camera}_{state}.png")
    print(f"images: {sorted(p.name for p in folder.glob('*.png'))} in {folder}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--decisions", type=int, default=12)
    parser.add_argument("--replan-every", type=int, default=8)
    parser.add_argument("--render-backend", choices=["cpu", "gpu"], default="cpu")
    parser.add_argument("--save-images", type=Path, default=None, help="also save both cameras, drawer closed/open")
    args = parser.parse_args()

    env = make_task_env(obs_mode="rgb", render_backend=args.render_backend)
    controller = ScriptedDrawerController()
    decisions_per_second(env, controller, at_decisions, 2, args.replan_every, seed=0)  # warm-up: shaders, caches
    rates = {name: decisions_per_second(env, controller, fn, args.decisions, args.replan_every, seed=100)
             for name, fn in (("every control step", every_step), ("at decisions only", at_decisions))}
    base = rates["every control step"]
    print(f"DrawerCubeTakeOut-v1, 2 cameras 224x224, render backend {args.render_backend}, "
          f"{args.decisions} decisions of {args.replan_every} control steps each")
    print("| cameras rendered | decisions/s | control steps/s | speed-up |")
    print("|---|---|---|---|")
    for name, rate in rates.items():
        print(f"| {name} | {rate:.2f} | {rate * args.replan_every:.1f} | {rate / base:.2f}x |")
    if args.save_images:
        save_images(env, args.save_images)
    env.close()


if __name__ == "__main__":
    main()
