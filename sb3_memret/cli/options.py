"""What the commands share: the ``--task``, ``--controller``, ``--render-backend``, ``--seeds`` and physics options,
their callbacks and defaults, and checks of a run folder against the options."""

from __future__ import annotations

import json
from pathlib import Path

import click

DEFAULT_TASK = "drawer"  # sb3_memret.tasks.DEFAULT_TASK
TASK_CONTROLLER = "  [default: the task's: its shipped camera-reading 'learned' where it has one, else scripted]"
RUN_CONTROLLER = "  [default: the run's]"


def task_or_default(task: str | None) -> str:
    """``task``, or the commands' default task when none is named."""
    return task or DEFAULT_TASK


def run_folder(experiment: str, task: str, seed: int) -> Path:
    """Where ``train`` writes a run by default: runs/EXPERIMENT-seedS for the default task, else
    runs/EXPERIMENT-TASK-seedS."""
    return Path("runs") / (f"{experiment}-seed{seed}" if task == DEFAULT_TASK else f"{experiment}-{task}-seed{seed}")


def default_controller(task: str | None) -> str:
    """The controller a command runs on ``task`` when none is named (``Task.default_controller``)."""
    from sb3_memret.tasks import make_task

    return make_task(task_or_default(task)).default_controller


def saved_task(spec: str, where: Path) -> str:
    """``spec``, the task a saved run names, once it can be made here; else a one-line error naming the run and why
    (a task of one's own whose module is not on PYTHONPATH, a task whose asset is missing)."""
    from sb3_memret.tasks import check_task_name

    try:
        return check_task_name(spec)
    except ValueError as err:
        raise click.ClickException(f"the run in {str(where)!r} plays task {spec!r}, which cannot be made here: "
                                   f"{err}") from None


def run_controller(folder: Path, task: str, default: str | None = None) -> str:
    """The controller the run in ``folder`` was trained with (its run.json, or the summary.json of a run from before
    runs recorded one at start); for a folder that holds no run, ``default`` (else ``task``'s default). A run that
    records none is a UsageError: guessing would silently serve another controller than it learned for."""
    for name in ("run.json", "summary.json"):
        record = folder / name
        if record.is_file() and (controller := json.loads(record.read_text()).get("controller")):
            return controller
    if (folder / "config.yml").exists():
        raise click.UsageError(f"the run in {str(folder)!r} records no controller (no run.json or summary.json: it "
                               "started before runs recorded theirs and never finished); pass --controller with the "
                               "one it was trained with")
    return default or default_controller(task)


def build_controller(ctx: click.Context, param: click.Parameter | None, value: str | None, task: str | None = None):
    """The controller ``value`` names for ``task`` (default: the command's ``--task``, else the drawer); None
    names the task's default controller."""
    from sb3_memret.controller_specs import make_controller

    task = task_or_default(task or ctx.params.get("task"))
    try:
        return make_controller(value or default_controller(task), task)
    except (ValueError, OSError, ImportError, RuntimeError) as err:  # bad spec, server down, missing extra or weights
        raise click.BadParameter(str(err), ctx=ctx, param=param) from err


def resolve_render_backend(ctx: click.Context, param: click.Parameter, value: str | None) -> str:
    """The render backend: by default the task's (``cpu`` for a task whose writer reads cameras, else
    ``none``); ``cpu`` is refused here, with the install command, when the project's lavapipe is missing."""
    if value is None:
        task = ctx.params.get("task")
        if task is None and any(p.name == "task" for p in ctx.command.params):
            return None  # the run's task decides (train --resume, eval): resolved by the command
        from sb3_memret.tasks import make_task

        value = make_task(task_or_default(task)).default_render_backend
    if value == "cpu":
        from sb3_memret.common.rendering import RendererNotFoundError, use_cpu_renderer

        try:
            use_cpu_renderer()
        except RendererNotFoundError as err:
            raise click.BadParameter(str(err), ctx=ctx, param=param) from None
    return value


def camera_render_backend(ctx: click.Context, render_backend: str, controller) -> str:
    """``render_backend``, or the software renderer where none was named and ``controller`` reads cameras."""
    named = ctx.get_parameter_source("render_backend") is not click.core.ParameterSource.DEFAULT
    if controller.spec.needs_images and render_backend == "none" and not named:
        return resolve_render_backend(ctx, None, "cpu")
    return render_backend


def render_backend_option(command):
    return click.option("--render-backend", type=click.Choice(["none", "cpu", "gpu"]), default=None,
                        callback=resolve_render_backend,
                        help="SAPIEN render backend; controllers that read camera images need cpu (the software "
                             "renderer of `make renderer`) or gpu  [default: cpu for a controller that reads "
                             "cameras, else the task's: none for the drawer, cpu for MIKASA's tasks, whose writer "
                             "reads the cameras]")(command)


def stop_options(command):
    """``--stop-at-greedy`` and ``--stop-patience``: end a training run once its held-out retrieval has reached a
    target (``StopOnRetrievalTarget``), not at the config's budget."""
    command = click.option("--stop-patience", type=click.IntRange(min=1), default=2, show_default=True,
                           help="With --stop-at-greedy: held-out evaluations in a row that must reach it.")(command)
    return click.option("--stop-at-greedy", type=click.FloatRange(0.0, 1.0, min_open=True), default=None,
                        metavar="ACCURACY",
                        help="Stop training once --stop-patience held-out evaluations in a row retrieve the true "
                             "memory greedily at least this often (e.g. 1.0)  [default: train the config's whole "
                             "budget]")(command)


class TaskName(click.ParamType):
    """A registered task name or ``package.module:Class``; a task that cannot run here says why."""

    name = "task"

    def convert(self, value, param, ctx):
        from sb3_memret.tasks import check_task_name

        try:
            return check_task_name(value)
        except ValueError as err:
            self.fail(str(err), param, ctx)


def task_option(default: str | None = DEFAULT_TASK):
    """``--task``: the memory task (parsed first, so the controller and render defaults follow it)."""
    def decorate(command):
        from sb3_memret.tasks import task_names

        return click.option("--task", type=TaskName(), default=default, is_eager=True,
                            show_default=default is not None,
                            help=f"Memory task: one of {', '.join(task_names())}, or package.module:Class (a Task "
                                 "of your own)." + ("" if default else "  [default: the run's]"))(command)
    return decorate


# ``--seeds`` by value: the task's held-out seed set it plays (Task.development_seeds, Task.evaluation_seeds)
SEED_SET_KINDS = {"dev": "development", "protocol": "evaluation"}


def seeds_option(otherwise: str):
    """``--seeds``: a task's development seeds unless its test set is asked for by name; ``otherwise`` says what a
    task without seed sets plays."""
    return click.option("--seeds", "seed_set", type=click.Choice(list(SEED_SET_KINDS)), default="dev",
                        show_default=True,
                        help="dev: the task's development seeds (MIKASA's 5000 + i), for every choice (checkpoints, "
                             "controllers, variants); protocol: its benchmark's test set (MIKASA's 4242424242 + i), "
                             "for the final figure only. " + otherwise)


def check_physics(ctx: click.Context, param: click.Parameter, value):
    """Refuse a Ray address beside a backend other than ray (checked once both values are known)."""
    backend = value if param.name == "backend" else ctx.params.get("backend")
    address = value if param.name == "ray_address" else ctx.params.get("ray_address")
    if address is not None and backend not in (None, "auto", "ray"):
        raise click.BadParameter(f"--ray-address {address!r} runs the physics on Ray, so --backend must be ray "
                                 f"(or left out), not {backend!r}", ctx=ctx, param=param)
    return value


def physics_options(command):
    """``--backend`` and ``--ray-address``: where the task physics runs, apart from the one controller."""
    command = click.option("--ray-address", default=None, metavar="ADDR", callback=check_physics,
                           help="Run the physics workers as Ray actors on this Ray cluster (e.g. ray://head:10001 "
                                "or auto); implies --backend ray.")(command)
    return click.option("--backend", type=click.Choice(["auto", "process", "gpu", "ray"]), default="auto",
                        show_default=True, callback=check_physics,
                        help="Where the task physics runs: auto (in-process for one env, else worker processes), "
                             "process (one CPU worker per env), gpu (one batched ManiSkill GPU simulation), ray "
                             "(Ray actors; a local Ray instance unless --ray-address). One controller call serves "
                             "every env whatever the backend.")(command)


def one_task_settings(settings: dict, task: str | None, where: Path) -> dict:
    """A saved model's decision-env settings for the one task a command plays: the run's own, or, for a learner
    across tasks, those of ``task``, which must be one of its tasks (such a learner names no single task itself)."""
    from sb3_memret.envs.multi_task import task_env_kwargs

    if "tasks" not in settings:
        return settings
    per_task = task_env_kwargs(settings)
    if task not in per_task:
        named = "names none" if task is None else f"was not trained on {task!r}"
        raise click.BadParameter(f"{str(where)!r} is a learner across {len(per_task)} tasks and --task {named}; "
                                 f"name one of: {', '.join(per_task)}", param_hint="--task")
    return per_task[task]


def check_run_task(ctx: click.Context, task: str | None, run_task: str, where: Path, controller: str,
              render_backend: str | None) -> str | None:
    """Check the run at ``where``: ``--task`` must match its task, and ``controller`` is built on it. Returns the
    render backend: ``render_backend``, or cpu where none was named and the controller reads cameras (else None:
    the run's task's)."""
    if task is not None and task != run_task:
        raise click.BadParameter(f"{str(where)!r} was trained on task {run_task!r}, not {task!r}", param_hint="--task")
    built = build_controller(ctx, None, controller, run_task)
    if render_backend is None and built.spec.needs_images:
        return resolve_render_backend(ctx, None, "cpu")
    return render_backend


def model_run(model_path: Path) -> Path:
    """The run folder a model file sits in (the folder itself, or its parent for checkpoints/)."""
    parent = Path(model_path).parent
    return parent.parent if not (parent / "config.yml").exists() and (parent.parent / "config.yml").exists() \
        else parent


def load_models(paths: list[Path], param_hint: str) -> list:
    from sb3_memret.policy.ppo import load_model

    try:
        return [load_model(path) for path in paths]
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint=param_hint) from None


def controller_spec(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """Check a controller spec in this process (kept in ``ctx.meta["controller"]``); envs built
    elsewhere (workers) receive the string. None stays None in a command whose run decides (its task and
    controller); elsewhere it becomes the task's default."""
    if value is None and any(p.name == "task" and p.default is None for p in ctx.command.params):
        return None
    value = value or default_controller(ctx.params.get("task"))
    ctx.meta["controller"] = build_controller(ctx, param, value)
    return value

