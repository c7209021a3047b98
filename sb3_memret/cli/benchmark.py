"""``sb3-memret benchmark``: a benchmark's own protocol, by one command."""

from __future__ import annotations

import os
from pathlib import Path

import click

from sb3_memret.benchmark.agent import CONDITIONS
from sb3_memret.benchmark.manifest import SEED_SETS, SPLITS
from sb3_memret.cli.options import stop_options


def _conditions(ctx: click.Context, param: click.Parameter, value: str) -> list[str]:
    from sb3_memret.benchmark.agent import check_conditions

    try:
        return check_conditions([c.strip() for c in value.split(",") if c.strip()])
    except ValueError as err:
        raise click.BadParameter(f"{value!r}: {err}") from None


def _tasks(ctx: click.Context, param: click.Parameter, value: str | None) -> list[str] | None:
    return None if value is None else [t.strip() for t in value.split(",") if t.strip()]


@click.group()
def benchmark() -> None:
    """Run a benchmark's official protocol with sb3-memret's agent as the policy."""


@benchmark.command()
@click.option("--split", type=click.Choice(SPLITS), default=None,
              help="The horizon split whose every task runs  [default: short, unless --tasks]")
@click.option("--tasks", callback=_tasks, default=None, metavar="ID[,ID...]",
              help="Exactly these tasks, instead of a split: MIKASA env ids, or package.module:Class for a task of "
                   "your own (its module on PYTHONPATH), which plays the env id its name gives.")
@click.option("--episodes", type=click.IntRange(min=1), default=50, show_default=True,
              help="Episodes per task and condition (the protocol's: 50).")
@click.option("--controller", default="scripted", show_default=True,
              help="The frozen controller (scripted: each task's expert, a privileged upper bound; scripted-camera: "
                   "the expert on the harness's inputs alone, for every MIKASA family (the tasks "
                   "sb3_memret.tasks.mikasa.camera_experts lists); learned: its shipped camera controller).")
@click.option("--conditions", callback=_conditions, default="none,oracle,wrong", show_default=True,
              metavar="C[,C...]", help=f"Prompt conditions, a comma list of {', '.join(CONDITIONS)}.")
@click.option("--seeds", "seed_set", type=click.Choice(sorted(SEED_SETS)), default="dev", show_default=True,
              help="dev: development seeds 5000 + i, for every choice (checkpoints, controllers, variants); protocol: "
                   "the benchmark's test seeds 4242424242 + i, for the final figure only (a published table asks "
                   "for them by name).")
@click.option("--learners", type=click.Path(path_type=Path), multiple=True,
              help="For recall: a folder with a trained memory learner per task, DIR/<env id>/final_model.zip, "
                   "one learner across tasks' model file (train recall --tasks), for every task it was trained on, "
                   "or `shipped`, the package's learner across the short split. Repeat it: each task plays the first "
                   "that serves it  [default: shipped]")
@click.option("--replan-every", type=click.IntRange(min=1), default=None,
              help="Control steps between controller calls  [default: each task's]")
@click.option("--workers", type=click.IntRange(min=1), default=min(2, os.cpu_count() or 1), show_default=True,
              help="Worker processes the episodes spread over.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Run folder: results.json, report.md, the episode log; an existing one resumes.")
@click.option("--scenes", type=click.Choice(["fresh", "reused"]), default=None,
              help="fresh: every episode in a scene built anew, so no episode depends on those its worker played "
                   "before (about 0.6 s an episode on a CPU); reused: the harness's own env, whose physics state "
                   "carries across resets  [default: a new --out's fresh, an existing one's own]")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
def mikasa(split: str | None, tasks: list[str] | None, episodes: int, controller: str, conditions: list[str],
           seed_set: str, learners: tuple[Path, ...], replan_every: int | None, workers: int, out: Path,
           scenes: str | None, progress: bool) -> None:
    """MIKASA-Robo-VLA's protocol through its own harness: every task of a split (or --tasks), each prompt
    condition, success once over seeded episodes (development seeds unless --seeds protocol asks for the test set);
    writes OUT/results.json and OUT/report.md (resumable). A learner that lands in --learners while the table plays
    (`benchmark learners` beside it) gets its recall episodes in a further pass."""
    from tqdm import tqdm

    from sb3_memret.benchmark.report import write_report
    from sb3_memret.benchmark.runner import Protocol, learners_landed, plan, resolve_task_ids, run_benchmark

    if split is not None and tasks is not None:
        raise click.UsageError("give --split or --tasks, not both")
    if split is None and tasks is None:
        split = "short"
    task_classes: tuple[tuple[str, str], ...] = ()
    if tasks is not None:
        try:
            tasks, task_classes = resolve_task_ids(tasks)
        except ValueError as err:
            raise click.BadParameter(str(err), param_hint="--tasks") from None
    protocol = Protocol(seed_set=seed_set, episodes=episodes, controller=controller, replan_every=replan_every,
                        task_classes=task_classes, fresh_scenes=_fresh_scenes(scenes, out))
    if "recall" in conditions:
        learners = _learner_sources(learners)
    try:
        run = plan(protocol, conditions, split, tasks, learners)
    except ValueError as err:
        raise click.UsageError(str(err)) from None
    for env_id, why in run.refused.items():
        click.echo(f"refused {env_id}: {why}", err=True)
    for (env_id, condition), why in run.refused_conditions.items():
        click.echo(f"refused {env_id} ({condition}): {why}", err=True)
    playable = [(row.env_id, c) for row in run.tasks if row.env_id not in run.refused for c in run.conditions
                if (row.env_id, c) not in run.refused_conditions]
    if not playable:  # nothing of what was asked can run: say why once, and fail
        why = next(iter(run.refused.values()), None) or next(iter(run.refused_conditions.values()), "no task asked")
        raise click.ClickException(f"nothing to play: {why}")
    bar = tqdm(total=None, unit="episode", disable=not progress, desc="benchmark")

    def on_progress(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    try:
        while True:
            content = run_benchmark(run, out, workers, on_progress,
                                    on_task_done=lambda content: write_report(content, out),
                                    on_outdated=lambda stale, replayed: _say_outdated(out, stale, replayed))
            landed = learners_landed(run)
            if not landed:
                break
            click.echo(f"learners landed for {', '.join(landed)}: playing their recall episodes", err=True)
            run = plan(protocol, conditions, split, tasks, learners)
            bar.reset()
    except ValueError as err:
        raise click.UsageError(str(err)) from None
    finally:
        bar.close()
    click.echo(str(write_report(content, out)))


def _fresh_scenes(scenes: str | None, out: Path) -> bool:
    """``--scenes``: as asked; else a run folder's own (one played before the option existed reused its scenes),
    and fresh for a new one."""
    import json

    from sb3_memret.benchmark.runner import PROTOCOL_FILE, RunFolder

    if scenes is not None:
        return scenes == "fresh"
    try:
        saved = RunFolder(out).protocol()
    except (json.JSONDecodeError, TypeError) as err:
        raise click.UsageError(f"{out / PROTOCOL_FILE} is not a protocol file the benchmark wrote: {err}") from None
    return True if saved is None else saved.fresh_scenes


def _learner_sources(learners: tuple[Path, ...]) -> tuple[Path, ...]:
    """``--learners`` with `shipped` (and the default, none given) read as the package's learner across the short
    split; a usage error naming how to rebuild it when it is missing."""
    from sb3_memret.benchmark.learners import learner_sources, shipped_learner

    if any(str(source) == "shipped" for source in learners) or not learners:
        try:
            shipped_learner()
        except FileNotFoundError as err:
            raise click.UsageError(str(err)) from None
    return learner_sources(learners or (Path("shipped"),))


def _say_outdated(out: Path, stale: dict[str, int], replayed: set[str]) -> None:
    """One line per kind: the logged episodes of ``out`` that changed code played, which this run plays again and
    which stay out of the table until a run asks for their tasks."""
    again = sorted(env_id for env_id in stale if env_id in replayed)
    left = sorted(env_id for env_id in stale if env_id not in replayed)
    if again:
        click.echo(f"{out}: {sum(stale[e] for e in again)} logged episodes of {', '.join(again)} were played by "
                   "code that has changed since (its controller or task digest): played again", err=True)
    if left:
        click.echo(f"{out}: {sum(stale[e] for e in left)} logged episodes of {', '.join(left)} were played by code "
                   "that has changed since and no longer count: the table shows those tasks unplayed until a run "
                   "asks for them (--tasks, or --split)", err=True)


@benchmark.command()
@click.option("--split", type=click.Choice(SPLITS), default=None,
              help="Train a learner for every task of this split  [default: short, unless --tasks]")
@click.option("--tasks", callback=_tasks, default=None, metavar="ID[,ID...]", help="Exactly these tasks.")
@click.option("--controller", default="scripted", show_default=True,
              help="The frozen controller the learners serve (the benchmark's --controller).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--eval-episodes", type=click.IntRange(min=1), default=50, show_default=True,
              help="Held-out episodes per evaluation during training (development seeds).")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Learners folder: OUT/<env id>/final_model.zip (benchmark mikasa --learners OUT).")
@stop_options
def learners(split: str | None, tasks: list[str] | None, controller: str, seed: int, eval_episodes: int,
             out: Path, stop_at_greedy: float | None, stop_patience: int) -> None:
    """Train the memory learner of every task of a split for the recall condition, one `train recall` run per task
    on its zoo config; finished runs are kept and interrupted ones resume. Prints the folder's learners at the end,
    a row a task (training minutes, how each run ended, held-out retrieval and success)."""
    from sb3_memret.analysis.learners import learner_rows, learners_table
    from sb3_memret.benchmark.learners import train_learners
    from sb3_memret.benchmark.manifest import select_tasks

    if split is not None and tasks is not None:
        raise click.UsageError("give --split or --tasks, not both")
    try:
        rows = select_tasks(split or ("short" if tasks is None else None), tasks)
    except ValueError as err:
        raise click.UsageError(str(err)) from None
    train_learners([row.env_id for row in rows], out, controller, seed, eval_episodes,
                   stop_at_greedy=stop_at_greedy, stop_patience=stop_patience,
                   on_outcome=lambda o: click.echo(f"{o.status} {o.env_id}: {o.detail}", err=True))
    click.echo("\n".join(learners_table(learner_rows(out))))


@benchmark.command("report")
@click.argument("run", type=click.Path(exists=True, file_okay=False, path_type=Path))
def report_command(run: Path) -> None:
    """Write RUN/results.json and RUN/report.md again from the run's episode log (a stopped run's table so far)."""
    from sb3_memret.benchmark.report import write_report
    from sb3_memret.benchmark.runner import rebuild

    try:
        content = rebuild(run)
    except (FileNotFoundError, ValueError, KeyError) as err:
        raise click.UsageError(f"{run} is not a benchmark run folder (results.json, protocol.json): {err}") from None
    click.echo(str(write_report(content, run)))


@benchmark.command("merge")
@click.argument("sources", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--into", type=click.Path(exists=True, file_okay=False, path_type=Path), required=True,
              help="The run folder that takes the episodes it lacks (one of the same protocol).")
@click.option("--split", type=click.Choice(SPLITS), default=None, help="Merge only the tasks of this split.")
@click.option("--tasks", callback=_tasks, default=None, metavar="ID[,ID...]", help="Merge only these tasks.")
def merge_command(sources: tuple[Path, ...], into: Path, split: str | None, tasks: list[str] | None) -> None:
    """Merge run folders played apart (SOURCES, of one protocol) into one table: each source's episodes that INTO
    lacks join its log, those played by other code, controller or learner are left out (and counted), and INTO's
    results.json and report.md are written again over all their tasks and conditions."""
    from sb3_memret.benchmark.manifest import select_tasks
    from sb3_memret.benchmark.merge import merge_runs
    from sb3_memret.benchmark.report import write_report

    try:
        only = None if split is None and tasks is None else [row.env_id for row in select_tasks(split, tasks)]
        merged = merge_runs(sources, into, only)
    except ValueError as err:
        raise click.UsageError(str(err)) from None
    for (env_id, condition), count in merged.added.items():
        click.echo(f"added {count} {condition} episodes of {env_id}", err=True)
    for source, count in merged.left_out.items():
        click.echo(f"left out {count} episodes of {source}: played by other code, controller or learner", err=True)
    if not merged.added:
        click.echo(f"{into} already held every current episode of {', '.join(map(str, sources))}", err=True)
    click.echo(str(write_report(merged.content, into)))


@benchmark.command("compare")
@click.argument("run_a", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("run_b", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--condition", default="oracle", show_default=True, type=click.Choice(CONDITIONS),
              help="The condition compared (RUN_A's).")
@click.option("--condition-b", default=None, type=click.Choice(CONDITIONS),
              help="RUN_B's condition, to set two conditions side by side (recall against oracle in one run, "
                   "say)  [default: --condition]")
def compare_command(run_a: Path, run_b: Path, condition: str, condition_b: str | None) -> None:
    """Two runs (RUN_A, RUN_B) paired episode by episode: each task at the seeds both played, the episodes only one
    won, and an exact McNemar test of them; then all tasks together. For choosing one controller or learner over
    another on development seeds."""
    from sb3_memret.benchmark.compare import load_results, paired_cells, render_comparison

    condition_b = condition_b or condition
    try:
        cells = paired_cells(load_results(run_a), load_results(run_b), condition, condition_b)
    except (FileNotFoundError, ValueError) as err:
        raise click.UsageError(str(err)) from None
    click.echo(render_comparison(cells, f"{run_a} ({condition})", f"{run_b} ({condition_b})"), nl=False)


__all__ = ["benchmark"]
