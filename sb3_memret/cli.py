"""The ``sb3-memret`` command line."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from sb3_memret.envs.cabinet import LAYERS

EXPERIMENTS = {"recall": "sb3_memret/DrawerRecall-v0"}
DEFAULT_CONFIG = Path(__file__).resolve().parents[1] / "zoo_configs" / "memret_ppo.yml"
HELD_OUT_SEED = 1_000_000


def _controller(ctx: click.Context, param: click.Parameter, value: str):
    from sb3_memret.controllers import make_controller

    try:
        return make_controller(value)
    except (ValueError, OSError, ImportError, RuntimeError) as err:  # bad spec, server down, missing extra or weights
        raise click.BadParameter(str(err), ctx=ctx, param=param) from err


def _render_backend_option(command):
    return click.option("--render-backend", type=click.Choice(["none", "cpu", "gpu"]), default="none", show_default=True,
                        help="SAPIEN render backend; controllers that read camera images need cpu or gpu.")(command)


def _controller_spec(ctx: click.Context, param: click.Parameter, value: str) -> str:
    """Check a controller spec in this process; envs built elsewhere (workers) receive the string."""
    _controller(ctx, param, value)
    return value


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
@_render_backend_option
def rollout(controller, condition: str, episodes: int, layer: int | None, seed: int, replan_every: int,
            as_json: bool, render_backend: str) -> None:
    """Run a frozen controller on DrawerCubeTakeOut-v1 and print success per layer."""
    from sb3_memret.rollout import evaluate_condition, summarize

    layers = (layer,) if layer else LAYERS
    with click.progressbar(length=episodes * len(layers), label=f"{condition} rollouts", file=sys.stderr) as bar:
        results = evaluate_condition(controller, condition, episodes, layers, seed, replan_every,
                                     on_episode=lambda _: bar.update(1), render_backend=render_backend)
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


@main.command()
@click.argument("experiment", type=click.Choice(list(EXPERIMENTS)))
@click.option("--config", "config_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help=f"rl-zoo-style YAML keyed by env id  [default: {DEFAULT_CONFIG.name} of the source tree]")
@click.option("--controller", default="scripted", show_default=True, callback=_controller_spec,
              help="Frozen controller the memory serves.")
@click.option("--n-envs", type=click.IntRange(min=1), default=None, help="Parallel envs (workers)  [default: config]")
@click.option("--timesteps", type=click.IntRange(min=1), default=None, help="Decisions in all  [default: config]")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Run folder  [default: runs/<experiment>-seed<seed>]")
@click.option("--resume", is_flag=True, help="Continue the run in --out from its last checkpoint.")
@click.option("--eval-episodes", type=click.IntRange(min=1), default=50, show_default=True,
              help="Held-out episodes per evaluation.")
@click.option("--eval-every", type=click.IntRange(min=1), default=5, show_default=True,
              help="Evaluate every N rounds (and at the end).")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
@_render_backend_option
def train(experiment: str, config_path: Path | None, controller: str, n_envs: int | None, timesteps: int | None,
          seed: int, out: Path | None, resume: bool, eval_episodes: int, eval_every: int, progress: bool,
          render_backend: str) -> None:
    """Train the retriever and retention networks with PPO on EXPERIMENT (recall: the drawer layer
    reaches the controller only through a retrieved memory)."""
    from sb3_memret.config import load_config
    from sb3_memret.training import RunOptions, format_history, train as run_training

    out = out or Path("runs") / f"{experiment}-seed{seed}"
    config = None
    if not resume or config_path or timesteps:
        try:
            config = load_config(config_path or DEFAULT_CONFIG, EXPERIMENTS[experiment])
        except (FileNotFoundError, ValueError) as err:
            raise click.BadParameter(str(err), param_hint="--config") from err
        if n_envs is not None:
            config.ppo["n_envs"] = n_envs
        if timesteps is not None:
            config.ppo["n_timesteps"] = timesteps
    options = RunOptions(out=out, controller=controller, seed=seed, resume=resume, eval_episodes=eval_episodes,
                         eval_every=eval_every, eval_seed=HELD_OUT_SEED, progress_bar=progress,
                         render_backend=render_backend)
    try:
        result = run_training(config, options)
    except (FileExistsError, FileNotFoundError) as err:
        raise click.UsageError(str(err)) from err
    click.echo(format_history(result.history))
    click.echo(f"\n{result.num_timesteps} decisions, {result.rounds} rounds in {result.wall_seconds / 60:.1f} min; "
               f"run folder {result.out}")
    if result.interrupted:
        click.echo(f"interrupted: saved {result.model_path}; continue with "
                   f"sb3-memret train {experiment} --out {result.out} --resume", err=True)
        sys.exit(130)
    click.echo(f"model: {result.model_path} (load with stable_baselines3.PPO.load)")


@main.command("eval")
@click.argument("model_path", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--condition", type=click.Choice(["recall", "oracle", "none"]), default="recall", show_default=True,
              help="recall: the layer only via retrieved memory; oracle: in the instruction; none: bare instruction.")
@click.option("--episodes", type=click.IntRange(min=1), default=50, show_default=True, help="Held-out episodes.")
@click.option("--controller", default="scripted", show_default=True, callback=_controller_spec,
              help="Frozen controller the memory serves.")
@click.option("--n-envs", type=click.IntRange(min=1), default=1, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=HELD_OUT_SEED, show_default=True,
              help="Seed of the evaluation episodes (training never uses it).")
@click.option("--stochastic", is_flag=True, help="Sample retrievals instead of acting greedily.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON on stdout.")
@_render_backend_option
def evaluate(model_path: Path, condition: str, episodes: int, controller: str, n_envs: int, seed: int,
             stochastic: bool, as_json: bool, render_backend: str) -> None:
    """Evaluate a trained model: success per layer and retrieval accuracy."""
    from sb3_memret.evaluation import evaluate_retrieval
    from sb3_memret.envs.vec_env import make_recall_vec_env
    from sb3_memret.policy.ppo import MemRetPPO
    from sb3_memret.training import eval_env_kwargs

    model = MemRetPPO.load(model_path, device="cpu")
    venv = make_recall_vec_env(n_envs, eval_env_kwargs(model, model_path, condition, controller, render_backend))
    try:
        with click.progressbar(length=episodes, label=f"{condition} evaluation", file=sys.stderr) as bar:
            report = evaluate_retrieval(model, venv, episodes, seed=seed, deterministic=not stochastic,
                                        on_episode=lambda _: bar.update(1))
    finally:
        venv.close()
    if as_json:
        click.echo(json.dumps({"model": str(model_path), "condition": condition, **report.to_dict()}))
        return
    label = "greedy" if not stochastic else "sampled"
    click.echo(f"model: {model_path}   condition: {condition}   episodes: {report.episodes}")
    click.echo(f"{label} retrieval accuracy: {report.greedy_accuracy:.1%} over {report.decisions} decisions "
               f"(sampled fraction {report.sampled_fraction:.1%}, entropy {report.entropy:.2f})")
    click.echo("| layer | episodes | success |")
    click.echo("|---|---|---|")
    for key in [str(layer) for layer in LAYERS] + ["overall"]:
        if key in report.success:
            count = report.episodes if key == "overall" else report.episodes_per_layer[key]
            click.echo(f"| {key} | {count} | {report.success[key]:.0%} |")
