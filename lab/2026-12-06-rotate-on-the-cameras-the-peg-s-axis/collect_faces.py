"""Collect the peg's cast top-face points and the true yaw along oracle episodes, for offline axis estimators."""
import sys, pickle
import numpy as np
from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.camera_experts import camera_expert
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.layout_perception import table_points
from sb3_memret.tasks.mikasa.rotate.task import peg_yaw, peg_top_mask, PEG_TOP_Z
task = make_task(sys.argv[1]); env = task.make_env(obs_mode="rgb")
out = []
for seed in [int(s) for s in sys.argv[2].split(",")]:
    obs, info = env.reset(seed=seed)
    frame = task.frames(env, obs, info, reset=True)[0]; episode = task.episode(frame)
    prompt = build_prompt(task.instruction(episode), task.oracle_facts(episode), task.template)
    ctl = camera_expert(task); ctl.reset([seed])
    for call in range(task.max_control_steps // task.replan_every):
        ch = ctl.act(obs, [prompt])[0]
        b = env.unwrapped
        rgb = np.asarray(as_numpy(obs["sensor_data"]["base_camera"]["rgb"][0]))
        mask = peg_top_mask(rgb)
        pts = table_points(np.argwhere(mask) + 0.5, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC, PEG_TOP_Z)
        out.append(dict(seed=seed, call=call, points=pts, yaw=float(as_numpy(peg_yaw(b.peg.pose.q)).reshape(-1)[0]),
                        centre=as_numpy(b.peg.pose.p).reshape(-1)[:2].copy(), tcp=as_numpy(obs["extra"]["tcp_pose"]).reshape(-1).copy()))
        for a in ch[: task.replan_every]:
            obs, _, _, _, info = env.step(a[None])
    print(seed, flush=True)
pickle.dump(out, open(sys.argv[3], "wb"))
