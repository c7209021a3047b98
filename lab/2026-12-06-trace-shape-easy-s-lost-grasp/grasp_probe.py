"""The camera TraceShape expert along oracle episodes at development seeds: per call (with a third argument), the hand,
the fingers' gap, the green cube against where the expert places it, whether it holds it, and MIKASA's checkpoints.

    .venv/bin/python lab/2026-12-06-trace-shape-easy-s-lost-grasp/grasp_probe.py TraceShapeEasy-VLA-v0 5020,5071 v
"""
import sys, numpy as np
from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.camera_experts import camera_expert
task = make_task(sys.argv[1]); env = task.make_env(obs_mode="rgb")
for seed in [int(s) for s in sys.argv[2].split(",")]:
    obs, info = env.reset(seed=seed); frame = task.frames(env, obs, info, reset=True)[0]; episode = task.episode(frame)
    ctl = camera_expert(task); ctl.reset([seed]); success = False
    for call in range(task.max_control_steps // task.replan_every):
        prompt = build_prompt(task.instruction(episode), task.facts_now("oracle", episode, frame, call), task.template)
        ch = ctl.act(obs, [prompt])[0]
        u = env.unwrapped
        tcp = as_numpy(obs["extra"]["tcp_pose"]).reshape(-1)[:3] if "extra" in obs else None
        true = as_numpy(u.green_cube.pose.p).reshape(-1)
        seen = ctl.cube.places[0]
        gap = as_numpy(obs["agent"]["qpos"]).reshape(-1)[7:9].sum()
        if len(sys.argv) > 3:
            print(f"{seed} call {call} tcp {np.round(100*tcp,1)} gap {gap:.3f} true {np.round(100*true,1)} seen {None if seen is None else np.round(100*seen,1)} grip {ctl.cube.grips[0] is not None} visited {as_numpy(u.checkpoint_visited).reshape(-1).astype(int)}")
        for a in ch[: task.replan_every]:
            obs, _, term, trunc, info = env.step(a[None]); frame = task.frames(env, obs, info)[0]; success |= frame.success
        if success: break
    print(seed, "success", success, "call", call)
