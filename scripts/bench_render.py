"""Camera rendering cost on DrawerCubeTakeOut-v1, each comparison measured in the same run:

- decisions/s with both 224x224 cameras rendered every control step against only at decisions
  (``execute_chunk``). A frozen controller reads images only when it is called, once per
  ``replan_every`` control steps, so the frames in between are never looked at. The scripted
  controller drives both arms (it reads state only), so the controller's cost is the same in both;
- milliseconds per picture of both cameras with ManiSkill's Panda (``panda``) against the drawer's
  light Panda (``panda_light``: visual meshes decimated, ``sb3_memret/tasks/drawer/robot.py``), at
  224x224 and at the camera controller's 128x128: what a picture costs is mostly the robot's triangles,
  not its pixels.

    python scripts/bench_render.py [--decisions 12] [--replan-every 8] [--pictures 20] [--render-backend cpu]
        [--save-images DIR]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer.drawer_cube import IMAGE_SIZE
from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
from sb3_memret.tasks.drawer.robot import LIGHT_PANDA_UID
from sb3_memret.tasks.drawer.prompts import condition_prompt
from sb3_memret.physics.chunks import execute_chunk


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


def picture_ms(robot: str, size: int, pictures: int, render_backend: str) -> float:
    """Milliseconds per observation with both cameras at ``size`` pixels, the robot ``robot`` (a warm-up left out)."""
    env = DrawerTask().make_env(obs_mode="rgb", render_backend=render_backend, robot_uids=robot,
                        sensor_configs={"width": size, "height": size})
    try:
        env.reset(seed=0, options={"target_layer": 2})
        task = env.unwrapped
        for _ in range(3):
            task.get_obs()
        start = time.perf_counter()
        for _ in range(pictures):
            task.get_obs()
        return (time.perf_counter() - start) / pictures * 1000
    finally:
        env.close()


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
    parser.add_argument("--pictures", type=int, default=20, help="observations timed per robot and size")
    parser.add_argument("--render-backend", choices=["cpu", "gpu"], default="cpu")
    parser.add_argument("--save-images", type=Path, default=None, help="also save both cameras, drawer closed/open")
    args = parser.parse_args()

    env = DrawerTask().make_env(obs_mode="rgb", render_backend=args.render_backend)
    controller = ScriptedDrawerController()
    decisions_per_second(env, controller, at_decisions, 2, args.replan_every, seed=0)  # warm-up: shaders, caches
    rates = {name: decisions_per_second(env, controller, fn, args.decisions, args.replan_every, seed=100)
             for name, fn in (("every control step", every_step), ("at decisions only", at_decisions))}
    base = rates["every control step"]
    print(f"DrawerCubeTakeOut-v1 ({env.unwrapped.agent.uid}), 2 cameras 224x224, render backend {args.render_backend}, "
          f"{args.decisions} decisions of {args.replan_every} control steps each")
    print("| cameras rendered | decisions/s | control steps/s | speed-up |")
    print("|---|---|---|---|")
    for name, rate in rates.items():
        print(f"| {name} | {rate:.2f} | {rate * args.replan_every:.1f} | {rate / base:.2f}x |")
    if args.save_images:
        save_images(env, args.save_images)
    env.close()

    costs = {(robot, size): picture_ms(robot, size, args.pictures, args.render_backend)
             for size in (IMAGE_SIZE, 128) for robot in ("panda", LIGHT_PANDA_UID)}
    reference = costs[("panda", IMAGE_SIZE)]
    print(f"\nboth cameras, one observation, mean of {args.pictures}")
    print("| robot | size | ms | speed-up vs panda at 224 |")
    print("|---|---|---|---|")
    for (robot, size), ms in costs.items():
        print(f"| {robot} | {size}x{size} | {ms:.1f} | {reference / ms:.2f}x |")


if __name__ == "__main__":
    main()
