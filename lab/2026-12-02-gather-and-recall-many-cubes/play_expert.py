"""Play GatherAndRecall N with the expert told the true flash: success, steps, flash frames read right."""
import sys, time
import numpy as np, torch
from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks.mikasa.gather_and_recall.task import GatherAndRecallTask, FLASH_COLOURS, INSTRUCTION, PROMPT_TEMPLATE, read_flash

env_id, n_ep = sys.argv[1], int(sys.argv[2])
task = GatherAndRecallTask(env_id)
env = task.make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu")
expert = task.expert()
for k in range(n_ep):
    seed = 5000 + k
    t = time.time()
    obs, info = env.reset(seed=seed)
    truth = FLASH_COLOURS[int(env.unwrapped.flash_color[0])]
    prompt = build_prompt(INSTRUCTION, [f"the flash was {truth}."], PROMPT_TEMPLATE)
    expert.reset([seed])
    success, flash, right, other, first = False, 0, 0, 0, None
    for step in range(task.max_control_steps):
        if step % 4 == 0:
            chunk = expert.act(obs, [prompt])[0]
        obs, _, term, trunc, info = env.step(torch.from_numpy(chunk[step % 4][None]).float())
        success |= bool(info["success"][0])
        read = read_flash(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0])
        if bool(info["flash_active"][0]):
            flash += 1; right += read == truth
            first = first or step
        else:
            other += read is not None
        if bool(term[0]) or bool(trunc[0]):
            break
    print(f"{env_id} seed {seed}: success {success} steps {step+1} on_disc {int(info['n_on_disc'][0])} "
          f"flash frames {flash} read right {right} false reads {other} flash at {first} ({time.time()-t:.0f}s)", flush=True)
