"""The camera Rotate expert's estimates against the simulator along oracle episodes at development seeds: per call,
the peg's axis and centre as it reads them, the wrist's angle as it dead-reckons it, and the episode's outcome.

    .venv/bin/python lab/2026-12-05-seven-more-families-on-the-cameras/rotate_probe.py \
        --task RotateStrictPos-VLA-v0 --seeds 4
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial.transform import Rotation

from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.camera_experts import camera_expert
from sb3_memret.tasks.mikasa.rotate.camera_expert import read_peg
from sb3_memret.tasks.mikasa.rotate.expert import hand_yaw, wrap
from sb3_memret.tasks.mikasa.rotate.task import peg_yaw


def tcp_gap(obs) -> float:
    return float(as_numpy(obs["agent"]["qpos"]).reshape(-1)[7:9].sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="RotateStrictPos-VLA-v0")
    parser.add_argument("--seeds", type=int, default=4, help="development seeds 5000 + i")
    parser.add_argument("--first", type=int, default=5000)
    parser.add_argument("--verbose", action="store_true", help="print every call")
    args = parser.parse_args()
    task = make_task(args.task)
    env = task.make_env(obs_mode="rgb")
    wins = 0
    for seed in range(args.first, args.first + args.seeds):
        obs, info = env.reset(seed=seed)
        frame = task.frames(env, obs, info, reset=True)[0]
        episode = task.episode(frame)
        prompt = build_prompt(task.instruction(episode), task.oracle_facts(episode), task.template)
        controller = camera_expert(task)
        controller.reset([seed])
        worst = {"yaw": 0.0, "centre": 0.0, "wrist": 0.0}
        success = False
        for call in range(task.max_control_steps // task.replan_every):
            chunk = controller.act(obs, [prompt])[0]
            base = env.unwrapped
            peg = controller.pegs[0]
            true_yaw = float(as_numpy(peg_yaw(base.peg.pose.q)).reshape(-1)[0])
            true_centre = as_numpy(base.peg.pose.p).reshape(-1)[:2]
            true_wrist = float(as_numpy(obs["agent"]["qpos"]).reshape(-1)[6])
            tcp = as_numpy(obs["extra"]["tcp_pose"]).reshape(-1)
            est_wrist = controller.wrist.angle(0, tcp.astype(np.float64))
            errors = {"wrist": abs(est_wrist - true_wrist)}
            held = controller.in_hand.offsets[0]
            raw = read_peg(obs["sensor_data"]["base_camera"]["rgb"][0])
            raw_text = "none" if raw is None else (f"{raw.pixels} px, yaw err "
                                                   f"{np.degrees(abs(float(wrap(raw.yaw - true_yaw)))):.1f} deg")
            if peg is not None:
                used = peg.yaw if held is None else hand_yaw(Rotation.from_quat(tcp[[4, 5, 6, 3]])) + held
                errors["yaw"] = abs(float(wrap(used - true_yaw)))
                errors["centre"] = float(np.linalg.norm(peg.centre - true_centre))
            worst = {k: max(worst[k], errors.get(k, 0.0)) for k in worst}
            if args.verbose:
                print(f"  call {call}: yaw err {np.degrees(errors.get('yaw', np.nan)):.1f} deg, centre err "
                      f"{100 * errors.get('centre', np.nan):.1f} cm, wrist {true_wrist:.2f} est {est_wrist:.2f}, "
                      f"pixels {None if peg is None else peg.pixels}, in hand {held is not None}, raw {raw_text}, "
                      f"gap {tcp_gap(obs):.3f}, tcp z {tcp[2]:.3f}")
            for action in chunk[: task.replan_every]:
                obs, _, _, _, info = env.step(action[None])
                success = success or bool(as_numpy(info["success"]).reshape(-1)[0])
        wins += success
        print(f"seed {seed}: success {success}; worst yaw {np.degrees(worst['yaw']):.1f} deg, centre "
              f"{100 * worst['centre']:.1f} cm, wrist {np.degrees(worst['wrist']):.1f} deg", flush=True)
    print(f"{wins}/{args.seeds}")


if __name__ == "__main__":
    main()
