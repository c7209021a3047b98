"""Which batteries move while the expert checks another, in one BatteriesChecker episode through the benchmark's
harness (the oracle condition, the scripted expert), and whether MIKASA counted it a success.

    python neighbour_probe.py SEED [--task BatteriesCheckerEasy-6-VLA-v0] [--grip 0.2] [--verbose]

``--grip`` sets the expert's pick opening (``expert.GRIP_PICK``: 0.2 opened the fingers 4 cm, 0.0 opens them 3 cm).
Development seeds only.
"""

import argparse

import numpy as np
import torch

import sb3_memret.tasks.mikasa.batteries_checker.expert as expert_module
from sb3_memret.benchmark import harness
from sb3_memret.benchmark.agent import MemoryAgent
from sb3_memret.controller_specs import make_controller
from sb3_memret.tasks import make_task

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("seed", type=int)
parser.add_argument("--task", default="BatteriesCheckerEasy-6-VLA-v0")
parser.add_argument("--grip", type=float, default=None)
parser.add_argument("--verbose", action="store_true")
args = parser.parse_args()
if args.grip is not None:
    expert_module.GRIP_PICK = args.grip

env, task = harness.make_env(args.task), make_task(args.task)
expert, n = make_controller("scripted", task), task.variant.batteries
base, step, moved, last, t = env.unwrapped, env.step, np.zeros(n), [], [0]


def spied_step(action):
    out = step(action)
    t[0] += 1
    now = torch.stack([b.pose.p[0] for b in base.batteries[:n]]).numpy()
    if last:
        others = [k for k in range(n) if k != expert.cycles[0].battery]
        went = np.linalg.norm(now - last[-1], axis=1)
        moved[others] += went[others]
        if args.verbose and went[others].max() > 1e-4:
            print(t[0], "moved", [k for k in others if went[k] > 1e-4], "while checking", expert.cycles[0].battery,
                  expert.cycles[0].stage, "tcp", np.round(base.agent.tcp.pose.p[0].numpy(), 3).tolist())
    last[:] = [now]
    return out


env.step = spied_step
agent = MemoryAgent(task, expert, "oracle", None)
agent.bind(env)
agent.begin(0)
result = harness.play_episode(env, agent, args.seed)
print(f"seed {args.seed} pick opening {expert_module.GRIP_PICK}: success {bool(result.success_once)} at "
      f"{result.n_steps} steps; batteries moved while another was checked (mm): {np.round(1000 * moved).tolist()}")
