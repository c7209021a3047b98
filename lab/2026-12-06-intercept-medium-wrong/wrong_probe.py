"""Trace the privileged Intercept expert told the wrong speed (the far end of the task's speeds) through MIKASA's
harness, fresh env per seed, development seeds: every decision's hand, fingers' gap and the ball (detector and
simulator), to see how a ball the plan expects far slower still ends on the target.

    .venv/bin/python lab/2026-12-06-intercept-medium-wrong/wrong_probe.py --seeds 5012 5027 5000
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_memret.benchmark.runner import Protocol, Unit, _Worker
from sb3_memret.controllers.base import as_numpy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="InterceptMedium-VLA-v0")
    parser.add_argument("--condition", default="wrong")
    parser.add_argument("--seeds", type=int, nargs="+", default=[5012])
    args = parser.parse_args()
    for seed in args.seeds:
        worker = _Worker(Protocol(seed_set="dev", episodes=100, controller="scripted"), None)
        agent = worker.agent(args.task, args.condition)
        base = worker.env.unwrapped
        act = agent.controller.act

        def traced(obs, prompts, *a, _act=act, **k):
            chunk = _act(obs, prompts, *a, **k)
            tcp = as_numpy(base.agent.tcp.pose.p)[0]
            ball = as_numpy(base.ball.pose.p)[0]
            vel = as_numpy(base.ball.linear_velocity)[0]
            goal = as_numpy(base.goal_region.pose.p)[0] if hasattr(base, "goal_region") else np.zeros(3)
            gap = float(as_numpy(base.agent.robot.get_qpos())[0, -2:].sum())
            print(f"  tcp {np.round(tcp, 3)} gap {gap:.3f} ball {np.round(ball, 3)} v {np.round(vel, 2)} "
                  f"ball-tcp {np.round(ball - tcp, 3)} goal-ball {np.linalg.norm((goal - ball)[:2]):.3f}")
            return chunk

        agent.controller.act = traced
        print(f"seed {seed} {args.condition}:")
        record = worker.play(Unit(args.task, args.condition, seed))
        print(f"seed {seed}: success {record['success']} steps {record['steps']}")


if __name__ == "__main__":
    main()
