"""Rotate camera expert per call: the peg's true and read angle, the goal, centres, the hand."""
import sys
import numpy as np
from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt, parse_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.camera_experts import camera_expert
from sb3_memret.tasks.mikasa.rotate.camera_expert import read_peg
from sb3_memret.tasks.mikasa.rotate.task import peg_yaw
task = make_task(sys.argv[1]); env = task.make_env(obs_mode="rgb")
for seed in [int(s) for s in sys.argv[2].split(",")]:
    obs, info = env.reset(seed=seed)
    frame = task.frames(env, obs, info, reset=True)[0]; episode = task.episode(frame)
    prompt = build_prompt(task.instruction(episode), task.oracle_facts(episode), task.template)
    ctl = camera_expert(task); ctl.reset([seed]); success = False
    rot, start = ctl.goal_of(parse_prompt(prompt, ctl.spec.prompt_template))
    print(seed, prompt[-80:], "goal deg", None if rot is None else np.degrees(start + rot) % 180)
    for call in range(task.max_control_steps // task.replan_every):
        ch = ctl.act(obs, [prompt])[0]
        b = env.unwrapped
        ty = np.degrees(float(as_numpy(peg_yaw(b.peg.pose.q)).reshape(-1)[0])) % 180
        tc = as_numpy(b.peg.pose.p).reshape(-1)[:2]
        peg = ctl.pegs[0]
        tcp = as_numpy(obs["extra"]["tcp_pose"]).reshape(-1)
        raw = read_peg(obs["sensor_data"]["base_camera"]["rgb"][0])
        print(f" c{call} true {ty:5.1f} read {np.degrees(peg.yaw) % 180 if peg else float('nan'):5.1f} centre true {np.round(100*tc,1)} read {np.round(100*peg.centre,1) if peg else None} tcp {np.round(100*tcp[:3],1)} raw {None if raw is None else (raw.pixels, round(100*raw.length,1))} a {np.round(ch[:4, :3].mean(0),2)}")
        for a in ch[: task.replan_every]:
            obs, _, _, _, info = env.step(a[None]); success |= bool(as_numpy(info["success"]).reshape(-1)[0])
    print(seed, "success", success)
