"""Does the BlinkCountButtonPress writer count the blinks right? Its fact, read from the base camera, against MIKASA's.

Plays a BlinkCountButtonPress task's env at ``--episodes`` development seeds (5000 + i; ``--seed`` for others), the
task's expert acting without a fact (through the cue it waits over the red button, as it does under every prompt),
the camera's frame perceived at every control step and read by the task's writer (``BlinkCountTask.perceive``,
``BlinkWriter``) until it writes or the cue has been over for longer than MIKASA's longest gap. Prints how many
counts were right, wrong (with the seeds, the truth and the reading) or never written, and the control step each
was written at against the step the phase lamp turned green (MIKASA's ``cue_steps_per_env``).

    .venv/bin/python lab/2026-11-27-blink-reader-error/blink_reader_error.py [--task BlinkCountButtonPressEasy-VLA-v0] [--episodes 40]
"""

from __future__ import annotations

import argparse
import collections

import torch

from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks.mikasa.blink_count.task import LONGEST_GAP, VARIANTS, BlinkCountTask
from sb3_memret.tasks.mikasa.core.cue_task import DEV_SEED
from sb3_memret.tasks.mikasa.blink_count.expert import parse_count


def read_count(task: BlinkCountTask, env, seed: int) -> tuple[int, int | None, int | None, int]:
    """One episode's truth, the writer's count (None: nothing written), the step it wrote at, and the step the cue
    ended at."""
    obs, info = env.reset(seed=seed)
    (frame,) = task.frames(env, obs, info, reset=True)
    frame.percepts = [task.perceive(env, obs)]
    writer, expert = task.writer(), task.expert()
    expert.reset([seed])
    prompt = build_prompt(task.instruction_text, [], task.prompt_template)
    cue_end = int(env.unwrapped.cue_steps_per_env[0])
    written = writer.read(frame)
    step, chunk = 0, None
    while not written and step < cue_end + LONGEST_GAP + 2:
        if step % task.replan_every == 0:
            chunk = expert.act(obs, [prompt])[0]
        obs, _, _, _, info = env.step(torch.from_numpy(chunk[step % task.replan_every][None]).float())
        step += 1
        (later,) = task.frames(env, obs, info)
        later.steps, later.percepts = 1, [task.perceive(env, obs)]
        written = writer.read(later)
    truth = frame.state["blinks"]
    if not written:
        return truth, None, None, cue_end
    ((_, predicates),) = written
    (value,) = predicates.values()
    return truth, parse_count(value), step, cue_end


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="BlinkCountButtonPressEasy-VLA-v0", choices=sorted(VARIANTS))
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--seed", type=int, default=DEV_SEED, help="the first seed")
    args = parser.parse_args()

    task = BlinkCountTask(args.task)
    env = task.make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    wrong, unwritten, lags = [], [], collections.Counter()
    try:
        for seed in range(args.seed, args.seed + args.episodes):
            truth, read, step, cue_end = read_count(task, env, seed)
            if read is None:
                unwritten.append(seed)
                continue
            lags[step - cue_end] += 1
            if read != truth:
                wrong.append((seed, truth, read))
    finally:
        env.close()
    right = args.episodes - len(wrong) - len(unwritten)
    print(f"{args.task}: {args.episodes} episodes at seeds {args.seed}-{args.seed + args.episodes - 1}: count right "
          f"{right}, wrong {len(wrong)}" + (f" (seed, truth, read: {wrong})" if wrong else "")
          + f", not written {len(unwritten)}" + (f" (seeds {unwritten})" if unwritten else ""))
    print("written at the cue's end + k steps, k: count " + ", ".join(f"{k}: {n}" for k, n in sorted(lags.items())))


if __name__ == "__main__":
    main()
