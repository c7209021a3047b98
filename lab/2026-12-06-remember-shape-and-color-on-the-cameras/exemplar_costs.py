"""Each object's cost as each shape at one frame of a Remember shape task (zero actions for STEPS steps), with how many
exemplars were seen at its place, against the simulator's layout.

    .venv/bin/python lab/2026-12-06-remember-shape-and-color-on-the-cameras/exemplar_costs.py RememberShapeAndColor5x3-VLA-v0 5000 12
"""
import sys
import numpy as np
from sb3_memret.controllers.base import as_numpy
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.find_imposter.camera_expert import one_frame
from sb3_memret.tasks.mikasa.find_imposter.perception import objects_in_view, object_crop, NEAR_PLACE
from sb3_memret.tasks.mikasa.remember.shape_camera_expert import _exemplars, candidates, exemplars_for
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES
task_id = sys.argv[1]; task = make_task(task_id); words = list(task.words)
cands = candidates(task_id, words); ex = _exemplars(exemplars_for(task_id))
env = task.make_env(obs_mode="rgb")
np.set_printoptions(precision=1, suppress=True, linewidth=200)
for seed in [int(s) for s in sys.argv[2].split(",")]:
    obs, _ = env.reset(seed=seed)
    for step in range(int(sys.argv[3])):
        obs, *_ = env.step(np.zeros(env.action_space.shape))
    frame = one_frame(obs["sensor_data"]["base_camera"]["rgb"])
    objs = objects_in_view(frame, 3, 15)
    base = env.unwrapped
    actors = [base.shape_actors[i] for i in sorted(base.shape_actors)]
    shapes = sorted(set(s for _, s in cands))
    print(seed, "objects", len(objs), "shapes", shapes)
    for o in objs:
        centre, crop = object_crop(frame, o.mask)
        near = np.linalg.norm(ex.centres - centre, axis=1) <= NEAR_PLACE
        c = ex.costs(frame, [o], shapes)[0]
        print(f"  fam {COLOUR_NAMES[o.family]:5s} px {o.mask.sum():3d} centre {np.round(centre,1)} near-exemplars {near.sum():2d} ({sorted(set(ex.shapes[near]))}) cost {np.round(c,1)}")
    for i, a in enumerate(actors):
        print("   truth", words[i], np.round(100*as_numpy(a.pose.p).reshape(-1)[:2],1))
