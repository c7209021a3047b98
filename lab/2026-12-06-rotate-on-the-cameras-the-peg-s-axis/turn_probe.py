"""The camera Rotate expert along oracle episodes at development seeds, per call: the peg's true and read angle, the
goal, the centres and the hand; with ``strips``, only the partial sightings (neither the whole face nor both ends),
each one's length, its density of pixels against the whole face's, and its angle's and far-end centre's errors.

    .venv/bin/python lab/2026-12-06-rotate-on-the-cameras-the-peg-s-axis/turn_probe.py RotateLenientPos-VLA-v0 5011,5014
    .venv/bin/python lab/2026-12-06-rotate-on-the-cameras-the-peg-s-axis/turn_probe.py RotateLenientPos-VLA-v0 5011 strips
"""
import sys
import numpy as np
from sb3_memret.controllers.base import as_numpy
from sb3_memret.controllers.prompts import build_prompt, parse_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.camera_experts import camera_expert
from sb3_memret.tasks.mikasa.rotate.camera_expert import EDGE, WHOLE_FRACTION, read_peg
from sb3_memret.tasks.mikasa.rotate.expert import PEG_HALF_LENGTH, wrap
from sb3_memret.tasks.mikasa.rotate.task import peg_yaw


def strip_line(seed, call, ctl, seen, true_yaw, true_centre, tcp):
    """A partial sighting's figures, or None for a whole one or both ends."""
    whole = ctl.wholes[0]
    if seen is None or whole is None or seen.pixels >= WHOLE_FRACTION * whole.pixels \
            or seen.length >= WHOLE_FRACTION * whole.length:
        return None
    far, near = sorted(seen.ends, key=lambda e: -float(np.linalg.norm(e - tcp[:2])))
    centre = far + (PEG_HALF_LENGTH - EDGE) * (near - far) / max(float(np.linalg.norm(near - far)), 1e-9)
    return (f"STRIP {seed} c{call} len {100 * seen.length:.1f} dens {seen.density / whole.density:.2f} yaw_err "
            f"{np.degrees(abs(float(wrap(seen.yaw - true_yaw)))):.1f} centre_err "
            f"{100 * np.linalg.norm(centre - true_centre):.1f}")


task = make_task(sys.argv[1]); env = task.make_env(obs_mode="rgb")
strips = len(sys.argv) > 3 and sys.argv[3] == "strips"
for seed in [int(s) for s in sys.argv[2].split(",")]:
    obs, info = env.reset(seed=seed)
    frame = task.frames(env, obs, info, reset=True)[0]; episode = task.episode(frame)
    prompt = build_prompt(task.instruction(episode), task.oracle_facts(episode), task.template)
    ctl = camera_expert(task); ctl.reset([seed]); success = False
    rot, start = ctl.goal_of(parse_prompt(prompt, ctl.spec.prompt_template))
    print(seed, prompt[-80:], "goal deg", np.degrees(start + rot) % 180)
    for call in range(task.max_control_steps // task.replan_every):
        ch = ctl.act(obs, [prompt])[0]
        b = env.unwrapped
        true_yaw = float(as_numpy(peg_yaw(b.peg.pose.q)).reshape(-1)[0])
        tc = as_numpy(b.peg.pose.p).reshape(-1)[:2]
        peg = ctl.pegs[0]
        tcp = as_numpy(obs["extra"]["tcp_pose"]).reshape(-1)
        raw = read_peg(obs["sensor_data"]["base_camera"]["rgb"][0])
        if strips:
            line = strip_line(seed, call, ctl, raw, true_yaw, tc, tcp)
            if line:
                print(line)
        else:
            print(f" c{call} true {np.degrees(true_yaw) % 180:5.1f} read "
                  f"{np.degrees(peg.yaw) % 180 if peg else float('nan'):5.1f} centre true {np.round(100 * tc, 1)} "
                  f"read {np.round(100 * peg.centre, 1) if peg else None} tcp {np.round(100 * tcp[:3], 1)} raw "
                  f"{None if raw is None else (raw.pixels, round(100 * raw.length, 1))} a {np.round(ch[:4, :3].mean(0), 2)}")
        for a in ch[: task.replan_every]:
            obs, _, _, _, info = env.step(a[None]); success |= bool(as_numpy(info["success"]).reshape(-1)[0])
    print(seed, "success", success, flush=True)
