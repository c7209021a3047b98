"""The ``sb3-memret`` command line."""

from __future__ import annotations

import json
import sys

import click

from sb3_memret.envs.cabinet import LAYERS


def _controller(ctx: click.Context, param: click.Parameter, value: str):
    from sb3_memret.controllers import make_controller

    try:
        return make_controller(value)
    except ValueError as err:
        raise click.BadParameter(str(err), ctx=ctx, param=param) from err


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="sb3-memret")
def main() -> None:
    """A learnable external language memory for frozen robot policies."""


@main.command()
@click.option("--controller", "controller", default="scripted", show_default=True, callback=_controller,
              help="Frozen controller to run: 'scripted' (CPU).")
@click.option("--condition", type=click.Choice(["oracle", "none", "wrong"]), default="oracle", show_default=True,
              help="Prompt: oracle names the cube's layer, wrong names another layer, none is the bare instruction.")
@click.option("--episodes", type=click.IntRange(min=1), default=10, show_default=True, help="Episodes per layer.")
@click.option("--layer", type=click.IntRange(min=min(LAYERS), max=max(LAYERS)), default=None,
              help="Only this layer (1 = top); default all three.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="First episode seed.")
@click.option("--replan-every", type=click.IntRange(min=1), default=8, show_default=True,
              help="Control steps executed from each action chunk before replanning.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON on stdout.")
def rollout(controller, condition: str, episodes: int, layer: int | None, seed: int, replan_every: int,
            as_json: bool) -> None:
    """Run a frozen controller on DrawerCubeTakeOut-v1 and print success per layer."""
    from sb3_memret.rollout import evaluate_condition, summarize

    layers = (layer,) if layer else LAYERS
    with click.progressbar(length=episodes * len(layers), label=f"{condition} rollouts", file=sys.stderr) as bar:
        results = evaluate_condition(controller, condition, episodes, layers, seed, replan_every,
                                     on_episode=lambda _: bar.update(1))
    summary = summarize(results)
    if as_json:
        click.echo(json.dumps({"condition": condition, "episodes": episodes, "success": summary["success"],
                               "median_steps_to_success": summary["median_steps_to_success"]}))
        return
    click.echo(f"condition: {condition}   episodes per layer: {episodes}")
    click.echo("| layer | success | median steps to success |")
    click.echo("|---|---|---|")
    for key, rate in summary["success"].items():
        steps = summary["median_steps_to_success"][key]
        click.echo(f"| {key} | {rate:.0%} | {'-' if steps is None else f'{steps:.0f}'} |")
