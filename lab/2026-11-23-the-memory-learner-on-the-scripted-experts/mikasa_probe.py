"""Probe MIKASA-Robo-VLA's cue tasks (RememberColor3/5/9, RememberShape3, SeqOfColors3, TakeItBack): the
scripted expert's success and the cue reader's accuracy, through the Task interface.

For each task, ``--episodes`` episodes at MIKASA's evaluation seeds (4242424242 + i; ``--seed`` for others) per
prompt condition: ``oracle`` (the task's true facts; its truth is read from the simulator only to build this
prompt), ``none`` (the bare instruction), ``wrong`` (the task's wrong facts) and, for a task that needs
several facts, ``missing`` (the oracle's facts without the last one). Success is MIKASA's success-once
over the episode (25 steps; TakeItBack's 60; SeqOfColors' 400, ended at success as the toolkit ends it). The expert
replans every ``--replan`` control steps, executing the first actions of each 8-step chunk. At every
step the base-camera frame goes through the task's reader (``Task.perceive``), scored against the
episode's phase (cue / delay / manipulation) and, in the cue, the item on show; a task that reads its cue
from the first frame alone (TakeItBack's start) has its writer's reading of that frame scored.

    .venv/bin/python lab/2026-11-23-the-memory-learner-on-the-scripted-experts/mikasa_probe.py [--tasks RememberColor9-VLA-v0 RememberShape3-VLA-v0] [--episodes 50]
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from dataclasses import dataclass, field

import torch


MIKASA_SEED = 4242424242
TASKS = ("RememberColor3-VLA-v0", "RememberColor5-VLA-v0", "RememberColor9-VLA-v0", "RememberShape3-VLA-v0",
         "SeqOfColors3-VLA-v0", "TakeItBack-VLA-v0")
CONDITIONS = ("oracle", "none", "wrong", "missing")


def make_env(task, obs_mode: str = "rgb", robot_uids: str = "panda"):
    """The task's env as the project runs it (CPU renderer, MIKASA's no-op wrapper, the controller's view);
    by default with the base camera only, the reader's."""
    return task.make_env(obs_mode=obs_mode, render_backend="cpu", sim_backend="cpu", robot_uids=robot_uids)


@dataclass
class CueStats:
    """Cue readings against the phase the frame was taken in."""

    confusion: Counter = field(default_factory=Counter)  # (true, read) in the cue phase
    false_readings: Counter = field(default_factory=Counter)  # phase -> frames read as a colour outside the cue
    frames: Counter = field(default_factory=Counter)  # phase -> frames
    seconds: float = 0.0

    def cue_accuracy(self) -> float:
        total = sum(self.confusion.values())
        return sum(n for (t, r), n in self.confusion.items() if t == r) / max(total, 1)


def phase_of(base, elapsed: int) -> str:
    """The episode's phase at ``elapsed`` steps (ground truth, for scoring only)."""
    cue = int(base.cue_steps_per_env[0])
    return "cue" if elapsed < cue else "delay" if elapsed < cue + int(base.empty_steps_per_env[0]) else "manip"


def shown_word(base, episode, elapsed: int) -> str:
    """The word the cue shows at ``elapsed`` (ground truth): a sequence's item on show, else the one cue's."""
    if len(episode.true_facts) == 1:
        return episode.group
    item = min(elapsed // int(base.cue_step_duration_per_env[0]), len(episode.true_facts) - 1)
    return episode.true_facts[item][1]


def condition_facts(task, episode, condition: str) -> list[str]:
    """The facts a condition's prompt carries."""
    if condition == "missing":
        return task.oracle_facts(episode)[:-1]
    return {"oracle": task.oracle_facts, "wrong": task.wrong_facts}.get(condition, lambda _: [])(episode)


def run_episode(task, env, controller, seed: int, condition: str, replan: int,
                stats: CueStats) -> tuple[bool, int, float]:
    """One episode; returns (success once, control steps, seconds spent in env.step)."""
    from sb3_memret.controllers.prompts import build_prompt

    obs, info = env.reset(seed=seed)
    frame = task.frames(env, obs, info, reset=True)[0]
    episode = task.episode(frame)  # metrics and the oracle prompt only
    if not task.perceives_every_step:  # the cue is the first frame (TakeItBack's start): score the writer's reading
        read = [value for _, predicates in task.writer().read(frame) for value in predicates.values()]
        stats.frames["cue"] += 1
        stats.confusion[(episode.group, read[0] if read else None)] += 1
    facts = condition_facts(task, episode, condition)
    prompt = build_prompt(task.instruction(episode), facts, controller.spec.prompt_template)
    controller.reset([seed])
    success, steps, env_seconds, chunk, done = False, 0, 0.0, None, False
    while True:
        if task.perceives_every_step:
            score_reading(task, env, obs, episode, int(info["elapsed_steps"][0]), stats)
        if done:
            break
        if steps % replan == 0:
            chunk = controller.act(obs, [prompt])[0]
        t0 = time.perf_counter()
        obs, _, terminated, truncated, info = env.step(torch.from_numpy(chunk[steps % replan][None]).float())
        env_seconds += time.perf_counter() - t0
        steps += 1
        success |= bool(info["success"][0])
        done = bool(terminated[0]) or bool(truncated[0]) or (success and task.ends_at_success)
    return success, steps, env_seconds


def score_reading(task, env, obs, episode, elapsed: int, stats: CueStats) -> None:
    """Read one control step's frame as the writer would and score it against the episode's phase."""
    t0 = time.perf_counter()
    reading = task.perceive(env, obs)
    stats.seconds += time.perf_counter() - t0
    phase = phase_of(env.unwrapped, elapsed)
    stats.frames[phase] += 1
    if phase == "cue":
        stats.confusion[(shown_word(env.unwrapped, episode, elapsed), reading)] += 1
    elif reading is not None:
        stats.false_readings[phase] += 1


def render_cost(task, steps: int = 50) -> dict[str, float]:
    """Seconds per env.step with zero actions in state_dict mode and in rgb mode (two 128x128 cameras)."""
    out = {}
    for mode in ("state_dict", "rgb"):
        env = make_env(task, obs_mode=mode, robot_uids="panda_wristcam")
        env.reset(seed=MIKASA_SEED)
        zero = torch.zeros(1, 7)
        t0 = time.perf_counter()
        for k in range(steps):
            _, _, te, tr, _ = env.step(zero)
            if bool(tr[0]) or bool(te[0]):
                env.reset(seed=MIKASA_SEED + k)
        out[mode] = (time.perf_counter() - t0) / steps
        env.close()
    return out


def report_cues(title: str, stats: CueStats) -> None:
    """Print the cue reader's accuracy in the cue phase, its per-colour confusion and its false readings."""
    n_cue = sum(stats.confusion.values())
    misread = {k: v for k, v in stats.confusion.items() if k[0] != k[1]}
    per_colour = Counter()
    for (true, _), n in stats.confusion.items():
        per_colour[true] += n
    print(f"{title}: {stats.cue_accuracy():.1%} of {n_cue} cue-phase frames right (frames per colour "
          f"{dict(sorted(per_colour.items()))}); misread {misread}; false readings {dict(stats.false_readings)} "
          f"in {dict(stats.frames)} frames; {1000 * stats.seconds / sum(stats.frames.values()):.2f} ms/frame",
          flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument("--conditions", nargs="+", default=list(CONDITIONS), choices=CONDITIONS)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed", type=int, default=MIKASA_SEED,
                        help="first episode seed: MIKASA's evaluation seeds by default; develop on others (e.g. 5000)")
    parser.add_argument("--replan", type=int, default=4, help="control steps executed of each chunk")
    parser.add_argument("--no-timing", action="store_true", help="skip the state-vs-rgb step timing")
    parser.add_argument("--cue-check", type=int, default=0, metavar="N",
                        help="also score the cue reader on N more oracle episodes per task, at seeds 0..N-1")
    args = parser.parse_args()

    from sb3_memret.tasks import make_task

    for env_id in args.tasks:
        task = make_task(env_id)
        env = make_env(task)
        controller = task.expert()
        controller.check_env(env)
        stats = CueStats()
        several = len(task.oracle_facts(task.episode(task.frames(env, *env.reset(seed=args.seed), reset=True)[0]))) > 1
        for condition in [c for c in args.conditions if c != "missing" or several]:
            wins, steps, seconds, t0 = 0, 0, 0.0, time.perf_counter()
            for i in range(args.episodes):
                ok, n, s = run_episode(task, env, controller, args.seed + i, condition, args.replan, stats)
                wins, steps, seconds = wins + ok, steps + n, seconds + s
            wall = time.perf_counter() - t0
            print(f"{env_id} {condition:6s} success_once {wins}/{args.episodes} = {wins / args.episodes:.0%}  "
                  f"env steps/s {steps / seconds:.1f} (env.step only), {steps / wall:.1f} (with reset, expert, "
                  f"cue reading)", flush=True)
        report_cues(f"{env_id} cue reading (the episodes above)", stats)
        if args.cue_check:
            stats, wins = CueStats(), 0
            for seed in range(args.cue_check):
                wins += run_episode(task, env, controller, seed, "oracle", args.replan, stats)[0]
            report_cues(f"{env_id} cue reading (seeds 0..{args.cue_check - 1}, oracle success {wins}/{args.cue_check})",
                        stats)
        env.close()
    if not args.no_timing:
        cost = render_cost(make_task(args.tasks[0]))
        print(f"{args.tasks[0]} s/step: state_dict {cost['state_dict']:.4f}, rgb {cost['rgb']:.4f} "
              f"(render of 2 cameras ~{cost['rgb'] - cost['state_dict']:.4f} s/step)")


if __name__ == "__main__":
    main()
