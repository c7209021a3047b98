"""The expert's check cycle step by step in one BatteriesChecker episode (the task's own env, oracle facts from
MIKASA's counters): at each change of MIKASA's counters or the expert's stage, the TCP, the battery under check, the
fingers' gap and whether MIKASA sees it grasped.

    python stage_probe.py SEED [--task BatteriesCheckerHard-3-VLA-v0] [--steps N] [--every FROM TO]

``--every FROM TO`` prints every decision between those control steps. Development seeds only.
"""

import argparse

import numpy as np

from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks import make_task

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("seed", type=int)
parser.add_argument("--task", default="BatteriesCheckerHard-3-VLA-v0")
parser.add_argument("--steps", type=int, default=None)
parser.add_argument("--every", type=int, nargs=2, default=(1, 0))
args = parser.parse_args()

task = make_task(args.task)
env = task.make_env(**task.env_kwargs(False, "cpu"))
expert = task.expert()
obs, info = env.reset(seed=args.seed)
expert.reset([args.seed])
frame = task.frames(env, obs, info, reset=True)[0]
episode = task.episode(frame)
base, t, success, last = env.unwrapped, 0, False, None
while t < (args.steps or task.max_control_steps) and not success:
    prompt = build_prompt(task.instruction_text, task.facts_now("oracle", episode, frame, t), task.prompt_template)
    for action in expert.act(obs, [prompt])[0][:task.replan_every]:
        obs, _, _, _, info = env.step(action)
        t += 1
        success |= bool(info["success"][0])
    frame = task.frames(env, obs, info)[0]
    cycle = expert.cycles[0]
    state = (int(info["checked_count"][0]), cycle.battery, cycle.stage, int(base.action_stage[0]))
    if state != last or args.every[0] <= t <= args.every[1]:
        k = cycle.battery
        battery = None if k is None else np.round(base.batteries[k].pose.p[0].numpy(), 3).tolist()
        held = None if k is None else bool(base.agent.is_grasping(base.batteries[k])[0])
        print(t, "checked, battery, stage, MIKASA's stage:", state, "tcp", np.round(base.agent.tcp.pose.p[0].numpy(), 3).tolist(),
              "battery", battery, "gap", round(float(base.agent.robot.get_qpos()[0, 7:9].sum()), 4), "grasped", held)
        last = state
print("success", success, "at", t, "socket", np.round(base.socket_slot_pos[0].numpy(), 3).tolist())
