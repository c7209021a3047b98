"""Per step of a Remember shape task's episodes (zero actions): how many objects the reader finds, and "+" where the
assignment names them all.

    .venv/bin/python lab/2026-12-06-remember-shape-and-color-on-the-cameras/groups_per_step.py RememberShapeAndColor5x3-VLA-v0 5004,5007
"""
import sys
import numpy as np
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.find_imposter.camera_expert import one_frame
from sb3_memret.tasks.mikasa.find_imposter.perception import objects_in_view, assign_shown
from sb3_memret.tasks.mikasa.remember.shape_camera_expert import candidates, exemplars_for, _exemplars
task_id = sys.argv[1]; task = make_task(task_id); words = list(task.words)
cands = candidates(task_id, words); ex = _exemplars(exemplars_for(task_id))
env = task.make_env(obs_mode="rgb")
for seed in [int(s) for s in sys.argv[2].split(",")]:
    obs, _ = env.reset(seed=seed); row = []
    for step in range(16):
        frame = one_frame(obs["sensor_data"]["base_camera"]["rgb"])
        objs = objects_in_view(frame, 3, 15)
        a = assign_shown(frame, cands, 15, ex)
        row.append(f"{step}:{len(objs)}{'' if a is None else '+'}")
        obs, *_ = env.step(np.zeros(env.action_space.shape))
    print(seed, " ".join(row), flush=True)
