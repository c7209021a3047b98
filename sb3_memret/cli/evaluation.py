"""What a trained run is worth: ``eval``, ``ablate``, ``trace``, ``plot`` and ``report``."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import click

from sb3_memret.cli.options import (RUN_CONTROLLER, SEED_SET_KINDS, TASK_CONTROLLER, build_controller,
                                    camera_render_backend, check_run_task, controller_spec, default_controller,
                                    load_models, model_run, one_task_settings, physics_options,
                                    render_backend_option, resolve_render_backend, run_controller, saved_task,
                                    seeds_option, task_option)
from sb3_memret.common.seeds import HELD_OUT_SEED
from sb3_memret.memory.retention import RETENTION_RULES


@click.command("eval")
@click.argument("model_path", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@task_option(default=None)
@click.option("--condition", type=click.Choice(["recall", "oracle", "none"]), default="recall", show_default=True,
              help="recall: the layer only via retrieved memory; oracle: in the instruction; none: bare instruction.")
@click.option("--episodes", type=click.IntRange(min=1), default=50, show_default=True, help="Held-out episodes.")
@click.option("--controller", default=None,
              help="Frozen controller the memory serves ('scripted': the run's task's expert)." + RUN_CONTROLLER)
@click.option("--n-envs", type=click.IntRange(min=1), default=1, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=HELD_OUT_SEED, show_default=True,
              help="Seed of the evaluation episodes (training never uses it).")
@seeds_option("A task without them (the drawer) plays episodes --seed draws.")
@click.option("--stochastic", is_flag=True, help="Sample retrievals instead of acting greedily.")
@click.option("--objects", default=None,
              help="A task with object sets (the drawer's train, heldout, ...): the set the episodes hide (heldout: "
                   "objects no training episode had)  [default: the run's]")
@click.option("--retention", type=click.Choice(list(RETENTION_RULES)), default=None,
              help="What evicts: the learned critic or a fixed rule (fifo, lru, prior)  [default: the run's]")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON on stdout.")
@render_backend_option
@physics_options
@click.pass_context
def evaluate(ctx: click.Context, model_path: Path, task: str | None, condition: str, episodes: int, controller: str, n_envs: int, seed: int,
             seed_set: str, stochastic: bool, objects: str | None, retention: str | None, as_json: bool,
             render_backend: str, backend: str, ray_address: str | None) -> None:
    """Evaluate a trained model: success per group (the drawer's layer, the cue's colour) and retrieval
    accuracy, at the task's development seeds where it has them (MIKASA's 5000 + i); its test set (MIKASA's
    4242424242 + i) only with --seeds protocol, for the final figure."""
    from sb3_memret.evaluation.retrieval import evaluate_retrieval
    from sb3_memret.envs.vec_env import make_recall_vec_env
    from sb3_memret.training.run import eval_env_kwargs

    from sb3_memret.tasks import make_task, task_in

    model, = load_models([model_path], "MODEL_PATH")
    kwargs = one_task_settings(eval_env_kwargs(model, model_path, condition, controller, render_backend), task,
                               model_path)
    run_spec = saved_task(task_in(kwargs), model_run(model_path))  # a registered name or package.module:Class
    run_task = make_task(run_spec)
    if task is not None and task != run_spec:
        raise click.BadParameter(f"{str(model_path)!r} was trained on task {run_spec!r}, not {task!r}",
                                 param_hint="--task")
    controller = controller or run_controller(model_run(model_path), run_spec)
    kwargs["controller"] = build_controller(ctx, None, controller, run_spec)
    kwargs["render_backend"] = render_backend or resolve_render_backend(
        ctx, None, "cpu" if kwargs["controller"].spec.needs_images else run_task.default_render_backend)
    if objects is not None:
        try:
            run_task.with_options(objects=objects)
        except ValueError as err:
            raise click.BadParameter(str(err), param_hint="--objects") from None
        kwargs["objects"] = objects
    if retention is not None:  # every store evicts by it, whatever rule its own config named
        from sb3_memret.envs.configs import with_retention

        kwargs = with_retention(kwargs, retention)
    venv = make_recall_vec_env(n_envs, kwargs, backend=backend, ray_address=ray_address)
    try:
        with click.progressbar(length=episodes, label=f"{condition} evaluation", file=sys.stderr) as bar:
            report = evaluate_retrieval(model, venv, episodes, seed=seed, deterministic=not stochastic,
                                        on_episode=lambda _: bar.update(1), held_out=SEED_SET_KINDS[seed_set])
    finally:
        venv.close()
    if as_json:
        click.echo(json.dumps({"model": str(model_path), "condition": condition, "objects": kwargs.get("objects", "cube"),
                               "retention": kwargs.get("retention", "learned"), **report.to_dict()}))
        return
    label = "greedy" if not stochastic else "sampled"
    click.echo(f"model: {model_path}   condition: {condition}   objects: {kwargs.get('objects', 'cube')}   "
               f"retention: {kwargs.get('retention', 'learned')}   episodes: {report.episodes}")
    click.echo(f"{label} retrieval accuracy: {report.greedy_accuracy:.1%} over {report.decisions} decisions "
               f"(sampled fraction {report.sampled_fraction:.1%}, entropy {report.entropy:.2f})")
    click.echo(f"| {run_task.group_name} | episodes | success |")
    click.echo("|---|---|---|")
    for key in list(report.episodes_per_group) + ["overall"]:
        count = report.episodes if key == "overall" else report.episodes_per_group[key]
        click.echo(f"| {key} | {count} | {report.success[key]:.0%} |")
    if report.needed_fact_gone_rate is not None:
        click.echo(f"before each task, the long-term store kept the target's true fact in {report.target_fact_kept_rate:.0%} "
                   f"of tasks, a stale one in {report.stale_fact_kept_rate:.0%}; needed fact gone (seen since the "
                   f"last move, not kept): {report.needed_fact_gone_rate:.0%}")


@click.command()
@click.argument("ablation")
@task_option()
@click.option("--controller", default=None, callback=controller_spec,
              help="Frozen controller to characterise." + TASK_CONTROLLER)
@click.option("--episodes", type=click.IntRange(min=1), default=17, show_default=True, help="Episodes per cell.")
@click.option("--seed", type=click.IntRange(min=0), default=HELD_OUT_SEED, show_default=True,
              help="First episode seed; every cell plays the same seeds.")
@click.option("--n-envs", type=click.IntRange(min=1), default=os.cpu_count() or 1, show_default=True,
              help="Envs played in parallel (all served by one controller).")
@click.option("--group", default=None,
              help="The group a table's episodes play where it plays one (the drawer's prompt table: the cube's "
                   "layer)  [default: the task's]")
@click.option("--intervals", default=None,
              help="A table that varies the replan interval: comma-separated intervals  [default: the task's]")
@click.option("--replan-every", type=click.IntRange(min=1), default=None,
              help="The other tables: control steps executed per action chunk  [default: the task's "
                   "(Task.replan_every)]")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Also write <ablation>.md, .csv and .json into this folder.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON on stdout instead of the table.")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
@render_backend_option
@physics_options
@click.pass_context
def ablate(ctx: click.Context, ablation: str, task: str, controller: str, episodes: int, seed: int, n_envs: int,
           group: str | None, intervals: str | None, replan_every: int | None, out: Path | None, as_json: bool,
           progress: bool, render_backend: str, backend: str, ray_address: str | None) -> None:
    """Characterise how a frozen controller consumes memory: ABLATION is one of the tables the task defines
    (Task.ablations). The drawer's are the seed paper's: replan (success per layer per replan interval, oracle
    memory), prompt (object word x layer number), memcount (zero, one or two memories) and wording (the oracle
    memory reworded as no training prompt was; these cells alone waive the prompt contract). A task without
    tables compares prompt conditions and replan intervals with `rollout --task T --condition oracle|none|wrong
    --replan-every N`."""
    from sb3_memret.analysis.ablations import run_ablation
    from sb3_memret.tasks.ablations import AblationOptions
    from sb3_memret.tasks import make_task

    the_task = make_task(task)
    tables = the_task.ablations()
    if ablation not in tables:
        accepted = f"one of {sorted(tables)}" if tables else (
            f"none: task {task!r} defines no ablation tables; compare prompt conditions and replan intervals with "
            f"`sb3-memret rollout --task {task} --condition oracle|none|wrong --replan-every N`")
        raise click.BadParameter(f"unknown ablation {ablation!r} for task {task!r}; expected {accepted}",
                                 param_hint="ABLATION")
    chunk_len = ctx.meta["controller"].spec.chunk_len
    render_backend = camera_render_backend(ctx, render_backend, ctx.meta["controller"])
    steps = None
    if intervals is not None:
        try:
            steps = tuple(int(i) for i in intervals.split(","))
        except ValueError:
            raise click.BadParameter(f"{intervals!r} is not a comma-separated list of integers",
                                     param_hint="--intervals") from None
    if replan_every is not None and replan_every > chunk_len:
        raise click.BadParameter(f"{replan_every} exceeds the controller's chunk length {chunk_len}",
                                 param_hint="--replan-every")
    try:
        spec = tables[ablation](AblationOptions(steps, group, replan_every))
    except ValueError as err:
        hint = "--group" if group is not None else "--intervals" if intervals is not None else "ABLATION"
        raise click.BadParameter(str(err), param_hint=hint) from None
    try:
        for cell in spec.cells:
            the_task.replan_interval(cell.replan_every, chunk_len)
    except ValueError:
        used = sorted({cell.replan_every for cell in spec.cells if cell.replan_every is not None})
        raise click.BadParameter(f"intervals {used} must lie in [1, {chunk_len}] (the controller's chunk length)",
                                 param_hint="--intervals") from None
    total = len(spec.cells) * episodes
    with click.progressbar(length=total, label=f"{ablation} ablation ({len(spec.cells)} cells)", file=sys.stderr,
                           hidden=not progress) as bar:
        result = run_ablation(spec, the_task, controller, episodes, seed, n_envs, render_backend,
                              on_episode=lambda *_: bar.update(1), backend=backend, ray_address=ray_address,
                              built=ctx.meta["controller"])
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / f"{ablation}.md").write_text(result.to_markdown() + "\n")
        (out / f"{ablation}.csv").write_text(result.to_csv())
        (out / f"{ablation}.json").write_text(json.dumps(result.to_dict(), indent=2))
    click.echo(json.dumps(result.to_dict()) if as_json else result.to_markdown())


def _trace_targets(paths: tuple[Path, ...]) -> list[Path]:
    """Model files to trace: a run folder stands for its initial and final models (before/after)."""
    from sb3_memret.training.run import INITIAL_MODEL

    targets = []
    for path in paths:
        if path.is_dir():
            pair = [path / INITIAL_MODEL, path / "final_model.zip"]
            missing = [p.name for p in pair if not p.exists()]
            if missing:
                raise click.BadParameter(f"run folder {str(path)!r} lacks {missing}; pass model files instead",
                                         param_hint="MODELS")
            targets += pair
        else:
            targets.append(path)
    return targets


@click.command()
@click.argument("models", nargs=-1, required=True, type=click.Path(exists=True, path_type=Path))
@task_option(default=None)
@click.option("--seed", type=click.IntRange(min=0), default=HELD_OUT_SEED, show_default=True,
              help="Episode whose first decision is traced (the same bank for every model).")
@click.option("--sample-seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the Plackett-Luce draw marked with '*'.")
@click.option("--controller", default=None, callback=controller_spec,
              help="Frozen controller the memory serves." + RUN_CONTROLLER)
@click.option("--json", "as_json", is_flag=True, help="Print the traces as JSON on stdout.")
@render_backend_option
def trace(models: tuple[Path, ...], task: str | None, seed: int, sample_seed: int, controller: str, as_json: bool,
          render_backend: str | None) -> None:
    """Show every memory in the bank at the first retrieval step with each model's retriever score
    ('*' = sampled, 'C' = the true memory). MODELS are model files or run folders (a run
    folder traces its untrained and final policies: before and after training)."""
    from sb3_memret.analysis.trace import model_label, trace_models
    from sb3_memret.tasks import task_in
    from sb3_memret.training.run import eval_env_kwargs

    paths = _trace_targets(models)
    loaded = list(zip(paths, load_models(paths, "MODELS")))
    settings = one_task_settings(eval_env_kwargs(loaded[0][1], paths[0], "recall", controller), task, paths[0])
    run_task = saved_task(task_in(settings), model_run(paths[0]))
    controller = controller or run_controller(model_run(paths[0]), run_task)
    render_backend = check_run_task(click.get_current_context(), task, run_task, paths[0], controller, render_backend)
    env_kwargs = one_task_settings(eval_env_kwargs(loaded[0][1], paths[0], "recall", controller, render_backend),
                                   task, paths[0])
    traces = trace_models([(model_label(m, p), m) for p, m in loaded], env_kwargs, seed, sample_seed)
    if as_json:
        click.echo(json.dumps([t.to_dict() for t in traces]))
        return
    click.echo(f'instruction: "{traces[0].instruction}"   episode seed {seed}, group {traces[0].group}   '
               f"( * = sampled, C = the true memory )")
    for t in traces:
        click.echo("\n" + t.format())


@click.command()
@click.argument("run", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="PNG to write  [default: RUN/learning_curves.png]")
def plot(run: Path, out: Path | None) -> None:
    """Plot the learning curves of a training run (the seed's Figure 5): held-out greedy accuracy, sampled
    fraction and success, the training draws that held the true memory, and policy entropy on a second axis."""
    from sb3_memret.analysis.plotting import plot_learning_curves
    from sb3_memret.training.run import retrieval_chance

    try:
        path = plot_learning_curves(run, out, chance=retrieval_chance(run))
    except (FileNotFoundError, ValueError) as err:
        raise click.UsageError(str(err)) from err
    click.echo(str(path))


@click.command()
@click.argument("run", type=click.Path(exists=True, file_okay=False, path_type=Path))
@task_option(default=None)
@click.option("--controller", default=None, callback=controller_spec,
              help="Frozen controller for the baseline evaluations and the trace." + RUN_CONTROLLER)
@click.option("--baseline-episodes", type=click.IntRange(min=0), default=None,
              help="Episodes of the oracle and no-memory baselines (0 skips them)  [default: as the final evaluation]")
@click.option("--n-envs", type=click.IntRange(min=1), default=os.cpu_count() or 1, show_default=True)
@click.option("--trace-seed", type=click.IntRange(min=0), default=None,
              help="Episode of the introspection trace  [default: the run's held-out seed]")
@render_backend_option
@physics_options
def report(run: Path, task: str | None, controller: str, baseline_episodes: int | None, n_envs: int,
           trace_seed: int | None, render_backend: str | None, backend: str, ray_address: str | None) -> None:
    """Write RUN/report.md: what was learned, the learning curves, the evaluation tables, the
    baselines, the before/after trace, any saved ablations and the configuration."""
    from sb3_memret.analysis.report import ReportOptions, write_report
    from sb3_memret.tasks import task_in
    from sb3_memret.training.run import load_run_config

    if (run / "config.yml").exists():
        settings = load_run_config(run).env_kwargs
        if "tasks" in settings:
            raise click.UsageError(f"{str(run)!r} is a learner across tasks, and a report covers one task's run; "
                                   f"evaluate it a task at a time: sb3-memret eval {run / 'final_model.zip'} --task ID")
        run_task = task_in(settings)
        controller = controller or run_controller(run, run_task)
        render_backend = check_run_task(click.get_current_context(), task, run_task, run, controller, render_backend)
    controller = controller or default_controller(task)

    options = ReportOptions(controller, baseline_episodes, n_envs, trace_seed, render_backend, backend, ray_address)
    try:
        path = write_report(run, options, on_progress=lambda step: click.echo(step + " ...", err=True))
    except (FileNotFoundError, ValueError) as err:
        raise click.UsageError(str(err)) from err
    click.echo(str(path))

