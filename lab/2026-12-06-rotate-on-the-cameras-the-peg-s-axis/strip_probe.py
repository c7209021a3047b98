"""Every partial sighting of the peg along oracle episodes: its length, density against the whole's, and how far
its angle and far-end centre are off the simulator's."""
import sys
import numpy as np
from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.camera_experts import camera_expert
from sb3_memret.tasks.mikasa.rotate.camera_expert import read_peg, EDGE, WHOLE_FRACTION
from sb3_memret.tasks.mikasa.rotate.expert import PEG_HALF_LENGTH, wrap
from sb3_memret.tasks.mikasa.rotate.task import peg_yaw
task = make_task(sys.argv[1]); env = task.make_env(obs_mode="rgb")
for seed in [int(s) for s in sys.argv[2].split(",")]:
    obs, info = env.reset(seed=seed)
    frame = task.frames(env, obs, info, reset=True)[0]; episode = task.episode(frame)
    prompt = build_prompt(task.instruction(episode), task.oracle_facts(episode), task.template)
    ctl = camera_expert(task); ctl.reset([seed]); success = False
    for call in range(task.max_control_steps // task.replan_every):
        ch = ctl.act(obs, [prompt])[0]
        whole = ctl.wholes[0]
        b = env.unwrapped
        ty = float(as_numpy(peg_yaw(b.peg.pose.q)).reshape(-1)[0]); tc = as_numpy(b.peg.pose.p).reshape(-1)[:2]
        seen = read_peg(obs["sensor_data"]["base_camera"]["rgb"][0])
        tcp = as_numpy(obs["extra"]["tcp_pose"]).reshape(-1)
        if seen is not None and whole is not None and seen.pixels < WHOLE_FRACTION * whole.pixels \
                and seen.length < WHOLE_FRACTION * whole.length:
            far, near = sorted(seen.ends, key=lambda e: -float(np.linalg.norm(e - tcp[:2])))
            inward = (near - far) / max(float(np.linalg.norm(near - far)), 1e-9)
            centre = far + (PEG_HALF_LENGTH - EDGE) * inward
            print(f"STRIP {seed} c{call} len {100*seen.length:.1f} dens {seen.density / whole.density:.2f} "
                  f"yaw_err {np.degrees(abs(float(wrap(seen.yaw - ty)))):.1f} centre_err {100*np.linalg.norm(centre - tc):.1f}", flush=True)
        for a in ch[: task.replan_every]:
            obs, _, _, _, info = env.step(a[None]); success |= bool(as_numpy(info["success"]).reshape(-1)[0])
    print(seed, "success", success, flush=True)
