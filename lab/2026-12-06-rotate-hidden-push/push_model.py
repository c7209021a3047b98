"""How far a push turns and slides the peg, per call of the camera Rotate expert along oracle episodes at development
seeds: the true peg before and after a call, the fingers' depth inside the peg before it (``pushed_peg``'s model on
the true peg, from the side the fingers came from), and the true turn and slide; a least-squares turn per metre.

    .venv/bin/python lab/2026-12-06-rotate-hidden-push/push_model.py RotateLenientPos-VLA-v0 5000 40
"""
import sys
import numpy as np
from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.camera_experts import camera_expert
from sb3_memret.tasks.mikasa.rotate.camera_expert import PegSighting, side_of
from sb3_memret.tasks.mikasa.rotate.expert import PEG_HALF_LENGTH, PEG_HALF_WIDTH, TurnGains, wrap
from sb3_memret.tasks.mikasa.rotate.task import peg_yaw

task = make_task(sys.argv[1]); env = task.make_env(obs_mode="rgb")
first, count = int(sys.argv[2]), int(sys.argv[3])
g = TurnGains()
rows = []


def true_peg(env):
    b = env.unwrapped
    yaw = float(as_numpy(peg_yaw(b.peg.pose.q)).reshape(-1)[0]) % np.pi
    return PegSighting(as_numpy(b.peg.pose.p).reshape(-1)[:2].astype(float), yaw, 0, np.zeros((2, 2)))


for seed in range(first, first + count):
    obs, info = env.reset(seed=seed)
    frame = task.frames(env, obs, info, reset=True)[0]; episode = task.episode(frame)
    prompt = build_prompt(task.instruction(episode), task.oracle_facts(episode), task.template)
    ctl = camera_expert(task); ctl.reset([seed]); side = None
    for call in range(task.max_control_steps // task.replan_every):
        chunk = ctl.act(obs, [prompt])[0]
        before = true_peg(env)
        for a in chunk[: task.replan_every]:
            obs, _, _, _, info = env.step(a[None])
        after = true_peg(env)
        tcp = as_numpy(obs["extra"]["tcp_pose"]).reshape(-1)
        hand = tcp[:2].astype(float)
        axis = np.array([np.cos(before.yaw), np.sin(before.yaw)]); normal = np.array([-axis[1], axis[0]])
        along, across = float((hand - before.centre) @ axis), float((hand - before.centre) @ normal)
        s = side if side is not None else (1.0 if across >= 0 else -1.0)
        depth = PEG_HALF_WIDTH + g.finger - s * across
        turn = float(wrap(after.yaw - before.yaw))
        slide = float((after.centre - before.centre) @ normal)
        if tcp[2] < g.push_z + 0.02 and abs(along) <= PEG_HALF_LENGTH and depth > 0:
            rows.append((seed, call, along, depth, turn, -s * slide, -s * np.sign(along)))
        new = side_of(after, hand, g)
        side = new if new is not None or tcp[2] >= 0.08 else side
rows = np.array(rows)
np.set_printoptions(precision=3, suppress=True)
print("seed call along depth turn slide sign")
for r in rows:
    print(f"{int(r[0])} c{int(r[1])} along {100 * r[2]:5.1f} depth {100 * r[3]:4.1f} turn {np.degrees(r[4]):6.1f} "
          f"slide {100 * r[5]:5.1f} expected sign {int(r[6])}")
x, y = rows[:, 3] * rows[:, 6], rows[:, 4]
print("calls", len(rows), "turn per metre (least squares through 0)", float(x @ y / (x @ x)))
for lo, hi in [(0, 0.02), (0.02, 0.04), (0.04, 0.08), (0.08, 1)]:
    m = (rows[:, 3] >= lo) & (rows[:, 3] < hi)
    if m.any():
        print(f"depth {100*lo:.0f}-{100*hi:.0f} cm: calls {m.sum()}, turn/depth median "
              f"{np.median(y[m] / x[m]):.2f} rad/m, slide/depth median {np.median(rows[m, 5] / rows[m, 3]):.2f}")
