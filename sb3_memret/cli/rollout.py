"""``sb3-memret rollout``: a frozen controller on a task under one prompt condition."""

from __future__ import annotations

import json
import sys

import click

from sb3_memret.cli.options import (SEED_SET_KINDS, TASK_CONTROLLER, build_controller, camera_render_backend,
                                    render_backend_option, seeds_option, task_option)


@click.command()
@task_option()
@click.option("--controller", "controller", default=None, callback=build_controller,
              help="Frozen controller to run: 'learned' (the task's shipped camera-reading policy), 'learned-state' "
                   "(the drawer's policy on the simulator's state), 'learned:PATH', 'scripted' (the task's expert), "
                   "'openpi://HOST:PORT' or 'lerobot:PATH'." + TASK_CONTROLLER)
@click.option("--condition", type=click.Choice(["oracle", "none", "wrong", "written"]), default="oracle",
              show_default=True,
              help="Prompt: oracle tells what must be remembered (the cube's layer, the cue's colour), wrong names "
                   "something else, none is the bare instruction, written carries every fact the task's writer has "
                   "written so far in the episode (no retriever, no decoys: it checks the writer end to end).")
@click.option("--episodes", type=click.IntRange(min=1), default=10, show_default=True,
              help="Episodes per group for a task whose episodes a command chooses by group (the drawer's layers), "
                   "else episodes in all.")
@click.option("--group", default=None,
              help="Only this group, for a task whose episodes a command chooses by group (Task.chosen_groups: the "
                   "drawer's layers 1-3, 1 = top)  [default: every group]")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="First episode seed: episodes play --seed, --seed + 1, ... on any task, instead of its seed set "
                   "(not with --seeds protocol)  [default: the task's seed set (--seeds) where it has one, else 0]")
@seeds_option("A task without them (the drawer) plays --seed onwards.")
@click.option("--replan-every", type=click.IntRange(min=1), default=None,
              help="Control steps executed from each action chunk before replanning  [default: the task's "
                   "(Task.replan_every): 8 on the drawer, 4 on MIKASA's tasks]")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON on stdout.")
@render_backend_option
def rollout(task: str, controller, condition: str, episodes: int, group: str | None, seed: int | None,
            seed_set: str, replan_every: int | None, as_json: bool, render_backend: str) -> None:
    """Run a frozen controller on a task under a prompt condition and print its success per group (the
    drawer's layer, the cue's colour), at the task's development seeds unless told otherwise (--seed, --seeds)."""
    from sb3_memret.evaluation.rollout import evaluate_task_condition, summarize
    from sb3_memret.tasks import make_task

    if seed is not None and seed_set == "protocol":
        raise click.BadParameter("--seeds protocol plays the task's own test set; give it or --seed, not both",
                                 param_hint="--seed")
    held_out = SEED_SET_KINDS[seed_set] if seed is None else None  # seeds of one's choosing: on any task
    the_task = make_task(task)
    render_backend = camera_render_backend(click.get_current_context(), render_backend, controller)
    try:
        groups = [the_task.group_reset_options(group)] if group is not None else \
            [the_task.group_reset_options(one) for one in the_task.chosen_groups()] or [None]
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="--group") from None
    with click.progressbar(length=episodes * len(groups), label=f"{condition} rollouts", file=sys.stderr) as bar:
        try:  # a chosen group's episodes: the same seeds as every other group's
            results = [result for options in groups for result in evaluate_task_condition(
                controller, condition, the_task, episodes, seed or 0, replan_every, on_episode=lambda _: bar.update(1),
                render_backend=render_backend, reset_options=options, held_out=held_out)]
        except ValueError as err:
            raise click.UsageError(str(err)) from err
    summary = summarize(results)
    if as_json:
        click.echo(json.dumps({"task": task, "condition": condition, "episodes": len(results),
                               "seeds": [r.seed for r in results], "success": summary["success"],
                               "median_steps_to_success": summary["median_steps_to_success"]}))
        return
    click.echo(f"task: {task}   condition: {condition}   episodes: {len(results)}")
    click.echo(f"| {the_task.group_name} | episodes | success | median steps to success |")
    click.echo("|---|---|---|---|")
    for key, rate in summary["success"].items():
        steps = summary["median_steps_to_success"][key]
        click.echo(f"| {key} | {summary['episodes'][key]} | {rate:.0%} | {'-' if steps is None else f'{steps:.0f}'} |")

