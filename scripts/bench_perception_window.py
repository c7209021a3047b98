"""What the writer's perception window saves in the training env: the same episodes through ``TaskRunner`` (what
every physics worker runs) with the task's window (the cameras render for its steps and at decisions) and with it
lifted (every step renders and is perceived), taking turns so that a shared machine's drift hits both alike.
Prints seconds and renders per episode, and the ratio.

Usage: ``python scripts/bench_perception_window.py [--task RememberColor3-VLA-v0] [--episodes 6]
[--controller scripted]``
"""

from __future__ import annotations

import argparse
import time

from sb3_memret.controller_specs import make_controller
from sb3_memret.common.obs_trees import stack_obs
from sb3_memret.physics.backends import TaskRunner
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.physics.sensor_gate import SensorGate
from sb3_memret.tasks import make_task


def play(runner: TaskRunner, task, controller, seed: int) -> None:
    """One oracle episode: the controller replans every ``task.replan_every`` steps."""
    frame = runner.reset(seed, {})
    episode = task.episode(frame)
    prompt = build_prompt(task.instruction(episode), task.oracle_facts(episode), controller.spec.prompt_template)
    controller.reset([seed])
    while not (frame.terminated or frame.truncated):
        frame = runner.execute(controller.act(stack_obs([frame.obs]), [prompt])[0][:task.replan_every])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="RememberColor3-VLA-v0")
    parser.add_argument("--controller", default="scripted")
    parser.add_argument("--episodes", type=int, default=6)
    args = parser.parse_args()
    task = make_task(args.task)
    if not task.perceives_every_step:
        raise SystemExit(f"{args.task}'s writer does not perceive every step: it has no perception window")
    controller = make_controller(args.controller, task)
    kwargs = task.env_kwargs(needs_images=controller.spec.needs_images, render_backend="cpu")
    runners = {"window": TaskRunner(kwargs, task.max_control_steps, task),
               "every step": TaskRunner(kwargs, task.max_control_steps, task)}
    runners["every step"].window = None
    seconds, renders = dict.fromkeys(runners, 0.0), dict.fromkeys(runners, 0)
    for name, runner in runners.items():
        gate = SensorGate.of(runner.env)
        render = gate._render

        def counted(*a, _name=name, _render=render, **k):
            renders[_name] += 1
            return _render(*a, **k)

        gate._render = counted
        play(runner, task, controller, 0)  # warm-up, left out
        renders[name] = 0
    try:
        for i in range(args.episodes):
            for name, runner in runners.items():
                start = time.perf_counter()
                play(runner, task, controller, 5000 + i)
                seconds[name] += time.perf_counter() - start
    finally:
        for runner in runners.values():
            runner.close()
    print(f"{args.task}, {args.controller} controller, {args.episodes} oracle episodes each "
          f"(window: {runners['window'].window} steps):")
    for name in runners:
        print(f"  {name:10s} {seconds[name] / args.episodes:6.2f} s/episode, {renders[name] / args.episodes:5.1f} "
              "renders/episode")
    print(f"  speed-up {seconds['every step'] / seconds['window']:.2f}x")


if __name__ == "__main__":
    main()
