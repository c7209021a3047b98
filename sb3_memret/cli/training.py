"""``sb3-memret train`` and ``tune``: the memory learner's PPO runs and hyperparameter search."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from sb3_memret.cli.options import (TASK_CONTROLLER, build_controller, default_controller, run_folder, task_or_default,
                                    physics_options, render_backend_option, resolve_render_backend, run_controller,
                                    stop_options, task_option)
from sb3_memret.common.seeds import HELD_OUT_SEED

EXPERIMENTS = ("recall",)
EXPERIMENT_ACROSS = "recall-across"  # a learner across tasks' default run folder: runs/recall-across-<tasks>-seed<seed>
MULTITASK_CONFIG, MULTITASK_SECTION = "memret_ppo_multitask.yml", "multitask"


@click.command()
@click.argument("experiment", type=click.Choice(list(EXPERIMENTS)), metavar="EXPERIMENT")
@task_option(default=None)
@click.option("--tasks", default=None, metavar="LIST",
              help="One learner across tasks instead of --task: a comma list of tasks, or mikasa:SPLIT (every "
                   "task of MIKASA-Robo-VLA's short / medium / long split that runs here). Its hyperparameters "
                   "are the config's 'multitask' section (zoo_configs/memret_ppo_multitask.yml); each task keeps "
                   "the env settings of its own section; --n-envs counts envs per task.")
@click.option("--config", "config_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="rl-zoo-style YAML keyed by task (its section named by the task's config_key, its name; a task "
                   "of your own passes its own YAML)  [default: the task's file in zoo_configs/ of the source tree: "
                   "memret_ppo.yml for the drawer, memret_ppo_mikasa.yml for MIKASA's tasks]")
@click.option("--controller", default=None,
              help="Frozen controller the memory serves ('scripted': the task's expert; 'learned': its camera-reading "
                   "policy, with --render-backend cpu)" + TASK_CONTROLLER + "; a resumed run keeps its own.")
@click.option("--n-envs", type=click.IntRange(min=1), default=None,
              help="Parallel envs; a round holds n_envs x n_steps decisions, so with many envs give the config "
                   "calibration_coef: 1.0 or fewer n_steps (docs: scaling out)  [default: config]")
@click.option("--timesteps", type=click.IntRange(min=1), default=None, help="Decisions in all  [default: config]")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Run folder  [default: runs/<experiment>-seed<seed>, runs/<experiment>-<task>-seed<seed> for "
                   "another task than the drawer]")
@click.option("--resume", is_flag=True, help="Continue the run in --out from its last checkpoint.")
@click.option("--retriever-from", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="Start the retriever from this model file's (e.g. a run of another benchmark task); the "
                   "retention critic starts fresh.")
@click.option("--eval-episodes", type=click.IntRange(min=1), default=None,
              help="Held-out episodes per evaluation  [default: the config's eval_episodes, else 50]")
@click.option("--eval-every", type=click.IntRange(min=1), default=None,
              help="Evaluate every N rounds (and at round 0 and the end)  [default: the config's eval_every, else 5]")
@click.option("--progress/--no-progress", default=True, show_default=True,
              help="Show a progress bar (without it, SB3 prints every round's statistics).")
@click.option("--report", "with_report", is_flag=True,
              help="Then write the run's report (as `sb3-memret report`), in this process and with the baselines "
                   "played on the run's own held-out workers.")
@stop_options
@render_backend_option
@physics_options
@click.pass_context
def train(ctx: click.Context, experiment: str, task: str | None, tasks: str | None, config_path: Path | None,
          controller: str, n_envs: int | None, timesteps: int | None, seed: int, out: Path | None, resume: bool,
          retriever_from: Path | None, eval_episodes: int | None, eval_every: int | None, progress: bool,
          with_report: bool, stop_at_greedy: float | None, stop_patience: int, render_backend: str, backend: str,
          ray_address: str | None) -> None:
    """Train the retriever and retention networks with PPO on EXPERIMENT (recall: what the task's controller
    must know, the drawer's layer or a cue's colour, reaches it only through a retrieved memory)."""
    from sb3_memret.training.config import load_task_config
    from sb3_memret.tasks import make_task, task_in
    from sb3_memret.training.run import RunOptions, load_run_config, start_retriever, train as run_training
    from sb3_memret.common.workers import exit_status

    if tasks is not None and task is not None:
        raise click.BadParameter("name one task (--task) or several (--tasks), not both", param_hint="--tasks")
    if tasks is not None and with_report:
        raise click.BadParameter("--report writes one task's report; a learner across tasks has none",
                                 param_hint="--report")
    if tasks is not None or (resume and out is not None and (out / "config.yml").exists()
                             and "tasks" in load_run_config(out).env_kwargs):
        config, options = across_tasks_run(tasks, config_path, controller, n_envs, timesteps, out,
                                           RunOptions(out=out or Path("."), seed=seed, resume=resume,
                                                      retriever_from=retriever_from, eval_episodes=eval_episodes,
                                                      eval_every=eval_every, eval_seed=HELD_OUT_SEED,
                                                      stop_at_greedy=stop_at_greedy, stop_patience=stop_patience,
                                                      progress_bar=progress, backend=backend,
                                                      ray_address=ray_address,
                                                      log_formats=_log_formats(progress)),
                                           render_backend, ctx)
        try:
            result = run_training(config, options)
        except (FileExistsError, FileNotFoundError) as err:
            raise click.UsageError(str(err)) from err
        _report_run(experiment, result, exit_status, across_tasks=True)
        return
    name = task_or_default(task)
    out = out or run_folder(experiment, name, seed)
    if resume and (out / "config.yml").exists():
        saved = task_in(load_run_config(out).env_kwargs)
        if task is not None and task != saved:
            raise click.BadParameter(f"the run in {str(out)!r} is of task {saved!r}, not {task!r}", param_hint="--task")
        name = saved
    the_task = make_task(name)
    config = None
    if not resume or config_path or timesteps:
        # a resume without --config keeps its run's own hyperparameters (--timesteps may lengthen it)
        from_run = resume and config_path is None and (out / "config.yml").exists()
        try:
            config = load_run_config(out) if from_run else load_task_config(name, config_path)
        except (FileNotFoundError, ValueError) as err:
            raise click.BadParameter(str(err), param_hint="--config") from err
        if config.env_kwargs.get("task", name) != name:
            raise click.BadParameter(f"section {the_task.config_key!r} of the config is for task "
                                     f"{config.env_kwargs['task']!r}, not {name!r}; pass --config FILE with a "
                                     f"section {the_task.config_key!r} for it", param_hint="--config")
        config.env_kwargs["task"] = name
        if n_envs is not None:
            config.ppo["n_envs"] = n_envs
        if timesteps is not None:
            config.ppo["n_timesteps"] = timesteps
    controller = controller or (run_controller(out, name) if resume else the_task.default_controller)
    built = build_controller(ctx, None, controller, name)
    # a controller that reads cameras gets the software renderer unless a backend is named
    render_backend = render_backend or resolve_render_backend(ctx, None, "cpu" if built.spec.needs_images
                                                       else the_task.default_render_backend)
    options = RunOptions(out=out, controller=controller, seed=seed, resume=resume, retriever_from=retriever_from,
                         eval_episodes=eval_episodes, eval_every=eval_every, eval_seed=HELD_OUT_SEED, progress_bar=progress,
                         stop_at_greedy=stop_at_greedy, stop_patience=stop_patience, render_backend=render_backend,
                         backend=backend, ray_address=ray_address, log_formats=_log_formats(progress),
                         report=_in_run_report(controller, render_backend, backend, ray_address) if with_report else None)
    if retriever_from is not None:
        try:
            start_retriever(config, options)
        except ValueError as err:
            raise click.BadParameter(str(err), param_hint="--retriever-from") from err
    try:
        result = run_training(config, options, built)
    except (FileExistsError, FileNotFoundError) as err:
        raise click.UsageError(str(err)) from err
    _report_run(experiment, result, exit_status)


def _log_formats(progress: bool) -> tuple[str, ...]:
    """The bar and the closing table say enough; without the bar, SB3's per-round dumps too."""
    return ("csv", "tensorboard") if progress else ("stdout", "csv", "tensorboard")


def across_tasks_run(tasks: str | None, config_path: Path | None, controller: str | None, n_envs: int | None,
                     timesteps: int | None, out: Path | None, options, render_backend: str | None,
                     ctx: click.Context):
    """The config and run options of one learner across ``tasks`` (``--tasks``; a resumed run keeps its own):
    the config's ``multitask`` section, each task's env settings of its own, a controller made per task."""
    import dataclasses

    from sb3_memret.training.config import ZOO_CONFIGS, load_config, resolve_task_settings
    from sb3_memret.tasks import make_task
    from sb3_memret.training.run import load_run_config

    seed, resume = options.seed, options.resume
    names = parse_tasks(tasks) if tasks is not None else None
    label = tasks.replace(":", "-") if tasks and tasks.startswith("mikasa:") else f"{len(names or [])}-tasks"
    out = out or Path("runs") / f"{EXPERIMENT_ACROSS}-{label}-seed{seed}"
    saved = load_run_config(out) if resume and (out / "config.yml").exists() else None
    if saved is not None and names is not None and list(saved.env_kwargs["tasks"]) != names:
        raise click.BadParameter(f"the run in {str(out)!r} is across tasks {list(saved.env_kwargs['tasks'])}, not "
                                 f"{names}", param_hint="--tasks")
    config = None
    if not resume or config_path or timesteps:
        try:
            config = saved if saved is not None and config_path is None else \
                load_config(config_path or ZOO_CONFIGS / MULTITASK_CONFIG, MULTITASK_SECTION)
        except (FileNotFoundError, ValueError) as err:
            raise click.BadParameter(str(err), param_hint="--config") from err
        if names is not None:
            config.env_kwargs.pop("task", None)
            config.env_kwargs["tasks"] = names
        if "tasks" not in config.env_kwargs:
            raise click.BadParameter(f"section {MULTITASK_SECTION!r} lists no tasks: pass --tasks", param_hint="--tasks")
        config = resolve_task_settings(config)
        if n_envs is not None:
            config.ppo["n_envs"] = n_envs
        if timesteps is not None:
            config.ppo["n_timesteps"] = timesteps
    names = list((config or saved).env_kwargs["tasks"])
    controller = controller or (run_controller(out, names[0], default="scripted") if resume else "scripted")
    if render_backend is None:  # cameras for any task whose writer reads them
        backends = {make_task(name).default_render_backend for name in names}
        render_backend = resolve_render_backend(ctx, None, next(iter(backends - {"none"}), "none"))
    return config, dataclasses.replace(options, out=out, controller=controller, render_backend=render_backend)


def parse_tasks(value: str) -> list[str]:
    """``--tasks``: a comma list of tasks (each as ``--task`` takes it), or ``mikasa:SPLIT``, the tasks of that
    split of MIKASA-Robo-VLA that run here (those that cannot are named, with why, on stderr)."""
    from sb3_memret.tasks import check_task_name

    if value.startswith("mikasa:"):
        from sb3_memret.benchmark.runner import split_tasks

        try:
            names, refused = split_tasks(value.removeprefix("mikasa:"))
        except ValueError as err:
            raise click.BadParameter(str(err), param_hint="--tasks") from None
        for name, why in refused.items():
            click.echo(f"left out {name}: {why}", err=True)
        return names
    names = [name.strip() for name in value.split(",") if name.strip()]
    if len(names) < 2 or len(set(names)) != len(names):
        raise click.BadParameter(f"{value!r}: a learner across tasks needs two or more distinct tasks, comma "
                                 "separated (one task: --task)", param_hint="--tasks")
    for name in names:
        try:
            check_task_name(name)
        except ValueError as err:
            raise click.BadParameter(str(err), param_hint="--tasks") from None
    return names


def _report_run(experiment: str, result, exit_status, across_tasks: bool = False) -> None:
    """The run's evaluation table and where its files are; an interrupted run says how to resume, and exits
    with the status of what stopped it. A learner across tasks is pointed at ``eval --task``, not ``report``."""
    from sb3_memret.training.run import format_history

    click.echo(format_history(result.history))
    click.echo(f"\n{result.num_timesteps} decisions, {result.rounds} rounds in {result.wall_seconds / 60:.1f} min; "
               f"run folder {result.out}")
    if result.target_reached is not None:
        click.echo(f"stopped at round {result.target_reached}: held-out greedy retrieval reached --stop-at-greedy")
    if result.interrupted:
        click.echo(f"stopped by {result.stopped_by}: saved {result.model_path}; continue with "
                   f"sb3-memret train {experiment} --out {result.out} --resume", err=True)
        sys.exit(exit_status(result.stopped_by))
    click.echo(f"model: {result.model_path} (load with stable_baselines3.PPO.load)")
    if result.report:
        click.echo(f"report: {result.report}")
    elif across_tasks:
        click.echo(f"evaluate: sb3-memret eval {result.model_path} --task ID (one of its tasks)")
    else:
        click.echo(f"report: sb3-memret report {result.out}")


def _in_run_report(controller: str, render_backend: str, backend: str, ray_address: str | None):
    """``train --report``: the report of a finished run, its baselines on the run's held-out envs."""
    def write(result, eval_env) -> Path:
        from sb3_memret.analysis.report import ReportOptions, write_report

        options = ReportOptions(controller, render_backend=render_backend, backend=backend, ray_address=ray_address)
        return write_report(result.out, options, on_progress=lambda step: click.echo(step + " ...", err=True),
                            venv=eval_env)

    return write


@click.command()
@click.argument("experiment", type=click.Choice(list(EXPERIMENTS)), metavar="EXPERIMENT")
@task_option()
@click.option("--config", "config_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Zoo config whose section is the starting point (everything the search does not vary)  "
                   "[default: the task's file in zoo_configs/]")
@click.option("--controller", default=None,
              help="Frozen controller the memory serves ('scripted': the task's expert)." + TASK_CONTROLLER)
@click.option("--trials", type=click.IntRange(min=1), default=20, show_default=True,
              help="Trials to run now (a study in --out continues with more).")
@click.option("--timesteps", type=click.IntRange(min=1), default=None, help="Decisions per trial  [default: config]")
@click.option("--n-envs", type=click.IntRange(min=1), default=None, help="Parallel envs  [default: config]")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Training seed of every trial, and the sampler's.")
@click.option("--eval-episodes", type=click.IntRange(min=1), default=20, show_default=True,
              help="Held-out episodes per evaluation (what the trials are compared and pruned on).")
@click.option("--eval-every", type=click.IntRange(min=1), default=2, show_default=True, help="Evaluate every N rounds.")
@click.option("--startup-trials", type=click.IntRange(min=0), default=5, show_default=True,
              help="Random trials before the TPE sampler models the space and the median pruner may prune.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Study folder: study.db, trial-N/ run folders, trials.csv, best_config.yml  "
                   "[default: runs/tune-<experiment>-<task>]")
@render_backend_option
@click.pass_context
def tune(ctx: click.Context, experiment: str, task: str, config_path: Path | None, controller: str, trials: int,
         timesteps: int | None, n_envs: int | None, seed: int, eval_episodes: int, eval_every: int, startup_trials: int,
         out: Path | None, render_backend: str) -> None:
    """Search the learner's hyperparameters on EXPERIMENT with Optuna, as rl-zoo does: TPE sampling, a median
    pruner on the held-out evaluations, and the best trial written as a zoo config (OUT/best_config.yml,
    ready for `train --config`). Trials are compared on their mean held-out greedy accuracy over the run
    (retrieval learned early and kept). An interrupted search continues when the same command runs again."""
    try:
        import optuna  # noqa: F401
    except ImportError:
        raise click.UsageError("tune needs Optuna: pip install 'sb3-memret[tune]' (or optuna)") from None
    from sb3_memret.training.config import load_task_config
    from sb3_memret.training.tuning import BEST_CONFIG, TRIALS_FILE, TuneOptions, tune as run_tune
    from sb3_memret.common.workers import exit_status

    try:
        config = load_task_config(task, config_path)
    except (FileNotFoundError, ValueError) as err:
        raise click.BadParameter(str(err), param_hint="--config") from err
    config.env_kwargs["task"] = task
    if n_envs is not None:
        config.ppo["n_envs"] = n_envs
    if timesteps is not None:
        config.ppo["n_timesteps"] = timesteps
    out = out or Path("runs") / f"tune-{experiment}-{task}"
    controller = controller or default_controller(task)
    built = build_controller(ctx, None, controller, task)
    options = TuneOptions(out=out, trials=trials, controller=controller, seed=seed, eval_episodes=eval_episodes,
                          eval_every=eval_every, eval_seed=HELD_OUT_SEED, startup_trials=startup_trials,
                          render_backend=render_backend)

    def on_trial(trial) -> None:
        value = "-" if trial.value is None else f"{trial.value:.3f}"
        click.echo(f"trial {trial.number}: {trial.state.name.lower()}, mean greedy accuracy {value}, {trial.params}",
                   err=True)

    try:
        study = run_tune(config, options, built, on_trial=on_trial)
    except KeyboardInterrupt as err:
        click.echo(f"stopped ({err or 'Ctrl-C'}); the study in {out} continues when the same command runs again",
                   err=True)
        sys.exit(exit_status(str(err) or "Ctrl-C"))
    best = out / BEST_CONFIG
    click.echo(f"{len(study.trials)} trials in {out / TRIALS_FILE}")
    if best.exists():
        click.echo(f"best: trial {study.best_trial.number}, mean greedy accuracy {study.best_value:.3f}; "
                   f"config {best} (sb3-memret train {experiment} --task {task} --config {best})")
    else:
        click.echo("no trial completed yet, so no best config", err=True)

