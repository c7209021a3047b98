"""Why does a touch controller fail? Per MIKASA touch episode: which cube the hand went to, how close it came to the
one it had to touch, and how far its perception put that cube.

Plays a controller with the oracle prompt at a RememberColor / RememberShape task's protocol seeds (as ``rollout``
does; ``--seeds dev`` for the development seeds, where choices are made) and, at every control step once the
candidates are in sight, reads the hand's position and each candidate's (the task's detector, privileged here: for
the diagnosis only). For a camera-reading learned controller it also
reads, at each decision, its perception head's estimate of the target's xy. Prints one line per episode and the
failures grouped: "went to another cube" (the hand ended nearest another candidate), "short of the target" (nearest
the target but never within the task's 5 cm), "reached, not held" (within 5 cm, no success: not still).

    python lab/2026-11-26-the-learned-controllers/touch_diagnosis.py --task RememberColor9-VLA-v0 --controller learned --episodes 50
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np
import torch

from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers.learned import LearnedController
from sb3_memret.physics.backends import TaskRunner
from sb3_memret.common.obs_trees import stack_obs
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.evaluation.rollout import task_env_kwargs
from sb3_memret.tasks import make_task

TOUCH_RADIUS = 0.05  # MIKASA's success radius around the target (m)


def perceived_target_xy(controller: LearnedController, obs, prompt: str, key: str, word: str) -> np.ndarray | None:
    """The controller's perception estimate of the ``word`` candidate's xy, or None when it estimates none."""
    names = controller.policy.config.perceived_names
    if f"{key}_{word}_x" not in names:
        return None
    inputs = controller.processor(obs, [prompt])
    policy = controller.policy
    with torch.no_grad():
        prompt_vector = policy.encode_prompts(inputs["tokens"], inputs["token_mask"])
    estimate = policy.estimate_perceived(policy.camera_features(inputs["images"]), prompt_vector, inputs["state"])[0]
    return np.array([float(estimate[names.index(f"{key}_{word}_{axis}")]) for axis in "xy"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="RememberColor9-VLA-v0")
    parser.add_argument("--controller", default="learned")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--replan-every", type=int, default=4)
    parser.add_argument("--seeds", choices=["protocol", "dev"], default="protocol",
                        help="the task's evaluation seeds, or its development seeds")
    args = parser.parse_args()

    task = make_task(args.task)
    if not hasattr(task, "detector_key"):
        raise SystemExit(f"task {task.name!r} is not a MIKASA touch task (RememberColor3/5/9, RememberShape3)")
    key, words = task.detector_key, task.words
    controller = make_controller(args.controller, task)
    runner = TaskRunner(task_env_kwargs(controller, task.default_render_backend, task), task.max_control_steps, task)
    outcomes: Counter[str] = Counter()
    print("| seed | target | success | nearest at the end | closest to target (cm) | perception error at decisions (cm) |")
    print("|---|---|---|---|---|---|")
    try:
        seeds = task.evaluation_seeds if args.seeds == "protocol" else task.development_seeds
        for seed in seeds(args.episodes):
            frame = runner.reset(seed, {})
            episode = task.episode(frame)
            target = words.index(episode.group)
            prompt = build_prompt(task.instruction(episode), task.oracle_facts(episode), controller.spec.prompt_template)
            controller.reset([seed])
            closest, nearest, errors, step, chunk = np.inf, None, [], 0, None
            while not (frame.terminated or frame.truncated):
                obs, offset = stack_obs([frame.obs]), step % args.replan_every
                if offset == 0:
                    chunk = controller.act(obs, [prompt])[0]
                extra = frame.obs["extra"]
                visible = np.asarray(extra[f"{key}_visible"]).reshape(-1) > 0.5
                if visible.all():
                    tcp = np.asarray(extra["tcp_pose"]).reshape(-1)[:3]
                    cubes = np.asarray(extra[f"{key}_positions"]).reshape(len(words), 3)
                    distances = np.linalg.norm(cubes - tcp, axis=1)
                    closest, nearest = min(closest, float(distances[target])), int(np.argmin(distances))
                    if offset == 0 and isinstance(controller, LearnedController):
                        estimate = perceived_target_xy(controller, obs, prompt, key, episode.group)
                        if estimate is not None:
                            errors.append(100 * float(np.linalg.norm(estimate - cubes[target, :2])))
                frame = runner.execute(chunk[offset: offset + 1])
                step += 1
            if frame.success:
                outcome = "success"
            elif nearest is not None and nearest != target:
                outcome = "went to another cube"
            elif closest > TOUCH_RADIUS:
                outcome = "short of the target"
            else:
                outcome = "reached, not held"
            outcomes[outcome] += 1
            went = "-" if nearest is None else words[nearest]
            error = f"{np.median(errors):.1f} (max {max(errors):.1f})" if errors else "-"
            print(f"| {seed} | {episode.group} | {frame.success} | {went} | {100 * closest:.1f} | {error} |", flush=True)
    finally:
        runner.close()
    print("\n| outcome | episodes |\n|---|---|")
    for outcome, count in outcomes.most_common():
        print(f"| {outcome} | {count} |")


if __name__ == "__main__":
    main()
