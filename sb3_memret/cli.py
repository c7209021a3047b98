"""The ``sb3-memret`` command line."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import click

from sb3_memret.envs.cabinet import LAYERS
from sb3_memret.envs.objects import OBJECT_SETS
from sb3_memret.memory.retention import RETENTION_RULES

EXPERIMENTS = ("recall",)
ZOO_CONFIGS = Path(__file__).resolve().parents[1] / "zoo_configs"
DEFAULT_TASK = "drawer"  # sb3_memret.tasks.DEFAULT_TASK
HELD_OUT_SEED = 1_000_000
TASK_CONTROLLER = ("  [default: the task's: learned-state on the drawer, the shipped camera-reading 'learned' on a task "
                   "that has one, else scripted]")
RUN_CONTROLLER = "  [default: the run's]"
DEMO_SEED = 100_000  # demonstrations never share a placement with rollout (0..) or held-out (1e6..) episodes


def load_task_config(task: str = DEFAULT_TASK, path: Path | None = None):
    """The hyperparameters of ``task``: its section (``Task.config_key``) of ``path``, by default of the task's own
    zoo config (``Task.zoo_config``). Without ``path``, a task that has no section there (a task of your own) is
    told where they were looked for and how to pass them: no other task's section stands in for its own."""
    from sb3_memret.config import MissingSectionError, load_config
    from sb3_memret.tasks import make_task

    the_task = make_task(task)
    default = ZOO_CONFIGS / the_task.zoo_config
    try:
        return load_config(path or default, the_task.config_key)
    except (FileNotFoundError, MissingSectionError) as err:
        if path is not None:
            raise
        raise MissingSectionError(f"no hyperparameters for task {task!r}: its zoo config ({err}); pass --config "
                                  f"FILE, a YAML with a section {the_task.config_key!r} (the task's config_key), e.g. "
                                  "a section of zoo_configs/ copied and renamed") from None


def _default_controller(task: str | None) -> str:
    """The controller a command runs on ``task`` when none is named (``Task.default_controller``)."""
    from sb3_memret.tasks import make_task

    return make_task(task or DEFAULT_TASK).default_controller


def _run_controller(folder: Path, task: str) -> str:
    """The controller the run in ``folder`` was trained with (its summary.json), else ``task``'s default."""
    summary = folder / "summary.json"
    if summary.is_file():
        name = json.loads(summary.read_text()).get("controller")
        if name:
            return name
    return _default_controller(task)


def _controller(ctx: click.Context, param: click.Parameter | None, value: str | None, task: str | None = None):
    """The controller ``value`` names for ``task`` (default: the command's ``--task``, else the drawer); None
    names the task's default controller."""
    from sb3_memret.controllers import make_controller

    task = task or ctx.params.get("task") or DEFAULT_TASK
    try:
        return make_controller(value or _default_controller(task), task)
    except (ValueError, OSError, ImportError, RuntimeError) as err:  # bad spec, server down, missing extra or weights
        raise click.BadParameter(str(err), ctx=ctx, param=param) from err


def _render_backend(ctx: click.Context, param: click.Parameter, value: str | None) -> str:
    """The render backend: by default the task's (``cpu`` for a task whose writer reads cameras, else
    ``none``); ``cpu`` is refused here, with the install command, when the project's lavapipe is missing."""
    if value is None:
        task = ctx.params.get("task")
        if task is None and any(p.name == "task" for p in ctx.command.params):
            return None  # the run's task decides (train --resume, eval): resolved by the command
        from sb3_memret.tasks import make_task

        value = make_task(task or DEFAULT_TASK).default_render_backend
    if value == "cpu":
        from sb3_memret.rendering import RendererNotFoundError, use_cpu_renderer

        try:
            use_cpu_renderer()
        except RendererNotFoundError as err:
            raise click.BadParameter(str(err), ctx=ctx, param=param) from None
    return value


def _camera_render_backend(ctx: click.Context, render_backend: str, controller) -> str:
    """``render_backend``, or the software renderer where none was named and ``controller`` reads cameras."""
    named = ctx.get_parameter_source("render_backend") is not click.core.ParameterSource.DEFAULT
    if controller.spec.needs_images and render_backend == "none" and not named:
        return _render_backend(ctx, None, "cpu")
    return render_backend


def _render_backend_option(command):
    return click.option("--render-backend", type=click.Choice(["none", "cpu", "gpu"]), default=None,
                        callback=_render_backend,
                        help="SAPIEN render backend; controllers that read camera images need cpu (the software "
                             "renderer of `make renderer`) or gpu  [default: cpu for a controller that reads "
                             "cameras, else the task's: none for the drawer, cpu for MIKASA's tasks, whose writer "
                             "reads the cameras]")(command)


class _TaskName(click.ParamType):
    """A registered task name or ``package.module:Class``; a task that cannot run here says why."""

    name = "task"

    def convert(self, value, param, ctx):
        from sb3_memret.tasks import check_task_name

        try:
            return check_task_name(value)
        except ValueError as err:
            self.fail(str(err), param, ctx)


def _task_option(default: str | None = DEFAULT_TASK):
    """``--task``: the memory task (parsed first, so the controller and render defaults follow it)."""
    def decorate(command):
        from sb3_memret.tasks import task_names

        return click.option("--task", type=_TaskName(), default=default, is_eager=True,
                            show_default=default is not None,
                            help=f"Memory task: one of {', '.join(task_names())}, or package.module:Class (a Task "
                                 "of your own)." + ("" if default else "  [default: the run's]"))(command)
    return decorate


def _check_physics(ctx: click.Context, param: click.Parameter, value):
    """Refuse a Ray address beside a backend other than ray (checked once both values are known)."""
    backend = value if param.name == "backend" else ctx.params.get("backend")
    address = value if param.name == "ray_address" else ctx.params.get("ray_address")
    if address is not None and backend not in (None, "auto", "ray"):
        raise click.BadParameter(f"--ray-address {address!r} runs the physics on Ray, so --backend must be ray "
                                 f"(or left out), not {backend!r}", ctx=ctx, param=param)
    return value


def _physics_options(command):
    """``--backend`` and ``--ray-address``: where the task physics runs, apart from the one controller."""
    command = click.option("--ray-address", default=None, metavar="ADDR", callback=_check_physics,
                           help="Run the physics workers as Ray actors on this Ray cluster (e.g. ray://head:10001 "
                                "or auto); implies --backend ray.")(command)
    return click.option("--backend", type=click.Choice(["auto", "process", "gpu", "ray"]), default="auto",
                        show_default=True, callback=_check_physics,
                        help="Where the task physics runs: auto (in-process for one env, else worker processes), "
                             "process (one CPU worker per env), gpu (one batched ManiSkill GPU simulation), ray "
                             "(Ray actors; a local Ray instance unless --ray-address). One controller call serves "
                             "every env whatever the backend.")(command)


def _run_task(ctx: click.Context, task: str | None, run_task: str, where: Path, controller: str,
              render_backend: str | None) -> str | None:
    """Check the run at ``where``: ``--task`` must match its task, and ``controller`` is built on it. Returns the
    render backend: ``render_backend``, or cpu where none was named and the controller reads cameras (else None:
    the run's task's)."""
    if task is not None and task != run_task:
        raise click.BadParameter(f"{str(where)!r} was trained on task {run_task!r}, not {task!r}", param_hint="--task")
    built = _controller(ctx, None, controller, run_task)
    if render_backend is None and built.spec.needs_images:
        return _render_backend(ctx, None, "cpu")
    return render_backend


def _model_run(model_path: Path) -> Path:
    """The run folder a model file sits in (the folder itself, or its parent for checkpoints/)."""
    parent = Path(model_path).parent
    return parent.parent if not (parent / "summary.json").exists() and (parent.parent / "summary.json").exists() \
        else parent


def _load_models(paths: list[Path], param_hint: str) -> list:
    from sb3_memret.policy.ppo import load_model

    try:
        return [load_model(path) for path in paths]
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint=param_hint) from None


def _controller_spec(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """Check a controller spec in this process (kept in ``ctx.meta["controller"]``); envs built
    elsewhere (workers) receive the string. None stays None in a command whose run decides (its task and
    controller); elsewhere it becomes the task's default."""
    if value is None and any(p.name == "task" and p.default is None for p in ctx.command.params):
        return None
    value = value or _default_controller(ctx.params.get("task"))
    ctx.meta["controller"] = _controller(ctx, param, value)
    return value


class _Cli(click.Group):
    """Every mistake ends in one line that names the value and what is accepted, with a non-zero
    exit status and no traceback; SIGTERM (a scheduler's stop) is handled as Ctrl-C."""

    def main(self, *args, **kwargs):  # type: ignore[override]
        from sb3_memret.errors import CudaNotFoundError, RendererNotFoundError, WeightsNotLoadedError
        from sb3_memret.workers import StopRequested, WorkerDiedError, exit_status, stop_signals_interrupt

        kwargs["standalone_mode"] = False  # errors come back here instead of click's usage block
        try:
            with stop_signals_interrupt():
                return super().main(*args, **kwargs)
        except click.exceptions.Abort as err:
            click.echo("Aborted.", err=True)
            sys.exit(exit_status(err.__cause__.signal_name if isinstance(err.__cause__, StopRequested) else "Ctrl-C"))
        except click.ClickException as err:
            ctx = getattr(err, "ctx", None)
            hint = f"  (see: {ctx.command_path} --help)" if isinstance(err, click.UsageError) and ctx else ""
            click.echo(f"Error: {err.format_message()}{hint}".replace("\n", " "), err=True)
            sys.exit(err.exit_code)
        except (WorkerDiedError, RendererNotFoundError, WeightsNotLoadedError, CudaNotFoundError) as err:
            click.echo(f"Error: {err}", err=True)
            sys.exit(1)


@click.group(cls=_Cli, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="sb3-memret")
def main() -> None:
    """A learnable external language memory for frozen robot policies."""


@main.command()
@_task_option()
@click.option("--controller", "controller", default=None, callback=_controller,
              help="Frozen controller to run: 'learned' (the task's shipped camera-reading policy), 'learned-state' "
                   "(the drawer's policy on the simulator's state), 'learned:PATH', 'scripted' (the task's expert), "
                   "'openpi://HOST:PORT' or 'lerobot:PATH'." + TASK_CONTROLLER)
@click.option("--condition", type=click.Choice(["oracle", "none", "wrong", "written"]), default="oracle",
              show_default=True,
              help="Prompt: oracle tells what must be remembered (the cube's layer, the cue's colour), wrong names "
                   "something else, none is the bare instruction, written carries every fact the task's writer has "
                   "written so far in the episode (no retriever, no decoys: it checks the writer end to end).")
@click.option("--episodes", type=click.IntRange(min=1), default=10, show_default=True,
              help="Episodes per layer (the drawer), else episodes in all.")
@click.option("--layer", type=click.IntRange(min=min(LAYERS), max=max(LAYERS)), default=None,
              help="The drawer only: this layer (1 = top); default all three.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="First episode seed (a task with protocol seeds, as MIKASA's, plays those instead, unless "
                   "--seeds dev).")
@click.option("--seeds", "seed_set", type=click.Choice(["protocol", "dev"]), default="protocol", show_default=True,
              help="protocol: a task's benchmark seeds where it has them (MIKASA's 4242424242 + i, its test set); "
                   "dev: --seed, --seed + 1, ... on every task, for development (e.g. --seed 5000).")
@click.option("--replan-every", type=click.IntRange(min=1), default=None,
              help="Control steps executed from each action chunk before replanning  [default: the task's "
                   "(Task.replan_every): 8 on the drawer, 4 on MIKASA's tasks]")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON on stdout.")
@_render_backend_option
def rollout(task: str, controller, condition: str, episodes: int, layer: int | None, seed: int, seed_set: str,
            replan_every: int | None, as_json: bool, render_backend: str) -> None:
    """Run a frozen controller on a task under a prompt condition and print its success per group (the
    drawer's layer, the cue's colour)."""
    from sb3_memret.rollout import evaluate_condition, evaluate_task_condition, summarize
    from sb3_memret.tasks import make_task

    replan_every = replan_every or make_task(task).replan_every

    render_backend = _camera_render_backend(click.get_current_context(), render_backend, controller)
    if task != DEFAULT_TASK and layer is not None:
        raise click.BadParameter(f"--layer chooses a drawer; task {task!r} has none", param_hint="--layer")
    layers = (layer,) if layer else LAYERS
    total = episodes * len(layers) if task == DEFAULT_TASK else episodes
    with click.progressbar(length=total, label=f"{condition} rollouts", file=sys.stderr) as bar:
        try:
            if task == DEFAULT_TASK and condition == "written":  # the same placements as the fixed prompts'
                results = [result for one in layers for result in evaluate_task_condition(
                    controller, condition, task, episodes, seed, replan_every, on_episode=lambda _: bar.update(1),
                    render_backend=render_backend, reset_options={"target_layer": one})]
            elif task == DEFAULT_TASK:
                results = evaluate_condition(controller, condition, episodes, layers, seed, replan_every,
                                             on_episode=lambda _: bar.update(1), render_backend=render_backend)
            else:
                results = evaluate_task_condition(controller, condition, task, episodes, seed, replan_every,
                                                  on_episode=lambda _: bar.update(1), render_backend=render_backend,
                                                  protocol_seeds=seed_set == "protocol")
        except ValueError as err:
            raise click.UsageError(str(err)) from err
    summary = summarize(results)
    if as_json:
        click.echo(json.dumps({"task": task, "condition": condition, "episodes": len(results),
                               "seeds": [r.seed for r in results], "success": summary["success"],
                               "median_steps_to_success": summary["median_steps_to_success"]}))
        return
    group = "layer" if task == DEFAULT_TASK else "group"
    click.echo(f"task: {task}   condition: {condition}   episodes: {len(results)}")
    click.echo(f"| {group} | episodes | success | median steps to success |")
    click.echo("|---|---|---|---|")
    for key, rate in summary["success"].items():
        steps = summary["median_steps_to_success"][key]
        click.echo(f"| {key} | {summary['episodes'][key]} | {rate:.0%} | {'-' if steps is None else f'{steps:.0f}'} |")


@main.command()
@_task_option()
@click.option("--episodes", type=click.IntRange(min=1), default=240, show_default=True, help="Episodes to record.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="New folder for the LeRobotDataset.")
@click.option("--seed", type=click.IntRange(min=0), default=DEMO_SEED, show_default=True,
              help="First placement seed (episodes use seed..seed+episodes-1).")
@click.option("--noise", type=click.FloatRange(min=0.0), default=0.05, show_default=True,
              help="Std of the Gaussian noise added to the executed arm actions of noisy episodes (labels stay clean).")
@click.option("--noisy-fraction", type=click.FloatRange(0.0, 1.0), default=0.5, show_default=True,
              help="Share of episodes played with action noise.")
@click.option("--learner", default=None,
              help="DAgger round: this controller (e.g. learned:PATH) acts while the expert labels every frame.")
@click.option("--n-envs", type=click.IntRange(min=1), default=os.cpu_count() or 1, show_default=True,
              help="Worker processes.")
@click.option("--objects", type=click.Choice(sorted(OBJECT_SETS)), default="cube", show_default=True,
              help="Objects the drawers hide; the targets cycle over them and the prompts name them.")
@click.option("--n-objects", type=click.IntRange(min=1, max=len(LAYERS)), default=1, show_default=True,
              help="Objects per episode, one per drawer.")
@click.option("--replan-every", type=click.IntRange(min=1), default=None,
              help="Control steps executed from each expert chunk  [default: the task's (Task.replan_every): 8 on the "
                   "drawer, 4 on MIKASA's short episodes]")
@click.option("--frames", type=click.Choice(["every", "decisions"]), default=None,
              help="Keep every control step (pi05 finetuning reads chunks from consecutive frames) or only the "
                   "decision steps, each with its chunk of labels, rendering the cameras only there  "
                   "[default: decisions with a render backend, else every]")
@click.option("--image-size", type=click.IntRange(min=16, max=224), default=None,
              help="Store camera images resized to this square size  [default: 224 drawer, 128 MIKASA]")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
@_render_backend_option
def demos(task: str, episodes: int, out: Path, seed: int, noise: float, noisy_fraction: float, learner: str | None,
          n_envs: int, objects: str, n_objects: int, replan_every: int | None, frames: str | None,
          image_size: int | None, progress: bool, render_backend: str) -> None:
    """Record the task's scripted expert as a LeRobotDataset (v3.0) for finetuning.

    \b
    Per frame: observation.state (19: end-effector state, drawer openings, cube detection, which is
    zero until the cube's drawer is open), action (the expert's 7-D end-effector delta pose), task
    (the exact prompt), and with --render-backend cpu|gpu the two cameras as
    observation.images.image / observation.images.wrist_image.
    \b
    Prompts in the data: the bare instruction (the expert opens the top drawer) in 20% of episodes,
    and "pick out the cube. the cube is in drawer layer L." naming the cube's layer (60%) or
    another layer (20%: the expert opens it, finds it empty and holds still). Kept out, so they
    stay held-out tests: two-memory prompts, other objects' and holding facts, and paraphrases.
    Off the expert's path: --noisy-fraction of the episodes run with --noise on the arm (clean
    labels), and --learner makes a DAgger round. Ctrl-C keeps every episode saved so far.
    With --objects train --n-objects 3 three objects hide in the drawers and the prompts name the
    target ("pick out the tin. the tin is in drawer layer L.").
    \b
    Other tasks (--task RememberColor3-VLA-v0 ...): the task's own frame layout (MIKASA: joints,
    hand pose, the object detector, both 128x128 cameras), episodes at seeds seed.. with the bare
    instruction (20%), the true fact ("... the cue cube was red.", 60%) or a wrong one (20%).
    """
    from tqdm import tqdm

    if out.exists():
        raise click.BadParameter(f"{str(out)!r} already exists; demonstrations go to a new folder", param_hint="--out")
    frames = frames or ("every" if render_backend == "none" else "decisions")
    if task != DEFAULT_TASK:
        if image_size not in (None, 128):
            raise click.BadParameter(f"MIKASA's cameras are 128x128; got {image_size}", param_hint="--image-size")
        for name, used in (("--objects", objects != "cube"), ("--n-objects", n_objects != 1)):
            if used:
                raise click.BadParameter(f"{name} applies to the drawer's demonstrations only, not task {task!r}",
                                         param_hint=name)
        if learner is not None:
            _controller(click.get_current_context(), None, learner, task)
        _task_demos(task, episodes, out, seed, noise, noisy_fraction, n_envs, replan_every, progress,
                    render_backend, frames, learner)
        return
    from sb3_memret.stage1.demos import plan_episodes, record_demos
    from sb3_memret.tasks.drawer import DrawerTask

    if learner is not None:
        _controller(click.get_current_context(), None, learner)
    planned = plan_episodes(episodes, seed, noise, noisy_fraction, objects=objects)
    wins = 0
    with tqdm(total=episodes, desc="demonstrations", unit="episode", disable=not progress) as bar:
        def on_episode(frames) -> None:
            nonlocal wins
            wins += frames.success
            bar.update(1)
            bar.set_postfix(success=f"{wins}/{bar.n}")

        record_demos(out, planned, render_backend, learner, n_envs, replan_every=replan_every or DrawerTask.replan_every,
                     on_episode=on_episode, objects=objects, n_objects=n_objects, frames=frames,
                     image_size=image_size or 224)
    click.echo(f"{episodes} episodes ({wins} successful) written to {out}")


def _task_demos(task: str, episodes: int, out: Path, seed: int, noise: float, noisy_fraction: float, n_envs: int,
                replan_every: int | None, progress: bool, render_backend: str, frames: str, learner: str | None) -> None:
    """``demos`` for a task other than the drawer, through the Task interface."""
    from tqdm import tqdm

    from sb3_memret.stage1.task_demos import plan_task_episodes, record_task_demos

    wins = 0
    with tqdm(total=episodes, desc=f"{task} demonstrations", unit="episode", disable=not progress) as bar:
        def on_episode(recorded) -> None:
            nonlocal wins
            wins += recorded.success
            bar.update(1)
            bar.set_postfix(success=f"{wins}/{bar.n}")

        try:
            record_task_demos(out, task, plan_task_episodes(episodes, seed, noise, noisy_fraction), render_backend,
                              n_envs, replan_every, on_episode=on_episode, frames=frames, learner=learner)
        except (NotImplementedError, ValueError) as err:
            raise click.UsageError(str(err)) from err
    click.echo(f"{episodes} episodes ({wins} successful) written to {out}")


@main.command()
@click.argument("datasets", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True, help="Checkpoint folder.")
@click.option("--policy", type=click.Choice(["learned", "pi05"]), default="learned", show_default=True,
              help="learned: the project's small policy (CPU, minutes); pi05: LoRA on lerobot's PI05.")
@click.option("--steps", type=click.IntRange(min=1), default=None,
              help="Gradient steps  [default: 8000 learned, 2000 pi05]")
@click.option("--batch-size", type=click.IntRange(min=1), default=None, help="[default: 256 learned, 8 pi05]")
@click.option("--lr", "learning_rate", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="[default: 1e-3 learned, 1e-4 pi05]")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--pretrained", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="pi05: the pretrained PI05 checkpoint folder.")
@click.option("--tokenizer", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="pi05: a local PaliGemma tokenizer folder.")
@click.option("--lora-rank", type=click.IntRange(min=1), default=16, show_default=True, help="pi05: LoRA rank.")
@click.option("--device", default="cpu", show_default=True, help="pi05: torch device.")
@_task_option()
@click.option("--state", type=click.Choice(["full", "proprio"]), default=None,
              help="learned: the state entries read: the task's whole layout (with the simulator's object "
                   "detection), or what a robot reads of itself (with cameras only)  [default: proprio when the "
                   "datasets have cameras, else full]")
@click.option("--image-encoder", type=click.Choice(["cnn", "efficientnet_lite0"]), default="efficientnet_lite0",
              show_default=True, help="learned: a CNN trained from pixels, or ImageNet EfficientNet-Lite0 frozen "
                                      "with trainable heads.")
@click.option("--image-dim", type=click.IntRange(min=1), default=64, show_default=True,
              help="learned: per camera, the size of the vector its head gives the action and perception heads.")
@click.option("--keypoints", type=click.IntRange(min=1), default=32, show_default=True,
              help="learned: per camera, the feature maps whose expected image coordinates its head reads (more for "
                   "scenes with more objects to locate).")
@click.option("--image-colour/--no-image-colour", default=False, show_default=True,
              help="learned, efficientnet_lite0: the camera heads also read the image's colour on the trunk's grid "
                   "(for objects told apart by hue alone).")
@click.option("--image-film/--no-image-film", default=False, show_default=True,
              help="learned: the camera heads' keypoints are conditioned on the prompt (FiLM), to find the object it "
                   "names among many alike.")
@click.option("--pointer/--no-pointer", default=False, show_default=True,
              help="learned: the action head also reads the perceived entries of the object the prompt points at "
                   "(attention over the perceived objects, named <object>_x/_y/_z/_visible), for scenes of many alike.")
@click.option("--pointer-hindsight", type=click.FloatRange(min=0.0), default=0.0, show_default=True,
              help="learned, with --pointer: weight of a cross-entropy that points each training prompt at the object "
                   "its demonstrations' hands end nearest (0: the pointer learns from the action loss alone).")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
def finetune(datasets: tuple[Path, ...], out: Path, policy: str, steps: int | None, batch_size: int | None,
             learning_rate: float | None, seed: int, pretrained: Path | None, tokenizer: Path | None, lora_rank: int,
             device: str, task: str, state: str | None, image_encoder: str, image_dim: int, keypoints: int,
             image_colour: bool, image_film: bool, pointer: bool, pointer_hindsight: float, progress: bool) -> None:
    """Train a frozen controller from DATASETS (LeRobotDatasets written by `sb3-memret demos`).

    The learned policy reads the prompt as frozen MiniLM per-token features, the state (and the
    cameras when the datasets have them) and predicts a 32 x 7 action chunk; the checkpoint
    (config.json + model.safetensors) loads as --controller learned:OUT. pi05 writes OUT/checkpoint
    and OUT/adapter, which load as --controller 'lerobot:OUT/checkpoint?adapter=OUT/adapter'.
    """
    from tqdm import tqdm

    if policy == "pi05":
        if pretrained is None:
            raise click.BadParameter("--policy pi05 needs --pretrained PATH (a PI05 checkpoint folder)",
                                     param_hint="--pretrained")
        if len(datasets) != 1:
            raise click.BadParameter(f"--policy pi05 trains on one dataset, got {len(datasets)}", param_hint="DATASETS")
        from sb3_memret.stage1.finetune_pi05 import finetune_pi05

        steps = steps or 2000
        with tqdm(total=steps, desc="finetune pi05 (LoRA)", disable=not progress) as bar:
            finetune_pi05(datasets[0], pretrained, out, steps=steps, batch_size=batch_size or 8,
                          learning_rate=learning_rate or 1e-4, lora_rank=lora_rank, device=device,
                          tokenizer=tokenizer, seed=seed, on_step=lambda step, loss: bar.update(1))
        tok = f"&tokenizer={tokenizer}" if tokenizer is not None else ""
        click.echo(f"LoRA adapter written: --controller 'lerobot:{out}/checkpoint?adapter={out}/adapter{tok}'")
        return
    if pretrained is not None or tokenizer is not None:
        raise click.BadParameter("--pretrained and --tokenizer apply to --policy pi05 only", param_hint="--policy")
    from sb3_memret.controllers.learned import LearnedPolicyConfig
    from sb3_memret.stage1.finetune import FinetuneSettings, has_cameras
    from sb3_memret.stage1.finetune import finetune as train_policy
    from sb3_memret.tasks import make_task

    settings = FinetuneSettings(steps=steps or 8000, batch_size=batch_size or 256,
                                learning_rate=learning_rate or 1e-3, seed=seed, pointer_hindsight=pointer_hindsight)
    if pointer_hindsight > 0 and not pointer:
        raise click.BadParameter(f"--pointer-hindsight {pointer_hindsight} trains the pointer: add --pointer",
                                 param_hint="--pointer-hindsight")
    the_task = make_task(task)
    template = the_task.prompt_template
    config = LearnedPolicyConfig(instructions=template.instructions, fact_templates=template.fact_templates,
                                 image_encoder=image_encoder, image_dim=image_dim, keypoints=keypoints,
                                 image_colour=image_colour, image_film=image_film, pointer=pointer,
                                 chunk_len=the_task.expert().spec.chunk_len)
    try:
        state = state or ("proprio" if has_cameras(datasets) else "full")
    except (FileNotFoundError, ValueError) as err:
        raise click.UsageError(str(err)) from err
    with tqdm(total=settings.steps, desc="finetune learned", disable=not progress) as bar:
        def on_step(step: int, loss: float) -> None:
            bar.update(1)
            if step % 100 == 0:
                bar.set_postfix(loss=f"{loss:.4f}")

        try:
            train_policy(datasets, out, config, settings=settings, on_step=on_step, task=task, state=state)
        except (FileNotFoundError, ValueError) as err:
            raise click.UsageError(str(err)) from err
    click.echo(f"checkpoint written: --controller learned:{out}")


@main.command()
@click.argument("controller", metavar="CONTROLLER")
@click.option("--host", default="0.0.0.0", show_default=True)
@click.option("--port", type=click.IntRange(1, 65535), default=8000, show_default=True)
def serve(controller: str, host: str, port: int) -> None:
    """Serve the frozen CONTROLLER (as --controller takes it) over openpi's websocket protocol, with
    openpi's own server: `--controller openpi://HOST:PORT` then runs it from any command. One Ctrl-C or
    SIGTERM stops it: open connections close once any inference in progress has replied."""
    from sb3_memret.stage1.serve import ControllerPolicy, serve as serve_policy

    try:
        policy = ControllerPolicy(controller)
    except (ValueError, OSError, ImportError, RuntimeError) as err:
        raise click.BadParameter(str(err), param_hint="CONTROLLER") from err
    click.echo(f"serving {controller} on ws://{host}:{port} (openpi protocol; Ctrl-C stops)", err=True)
    try:
        serve_policy(policy, host, port)
    except OSError as err:  # it could not listen there (the port is taken, say)
        raise click.BadParameter(f"cannot serve on {host}:{port}: {err.strerror or err}", param_hint="--port") from err


@main.command()
@click.argument("experiment", type=click.Choice(list(EXPERIMENTS)), metavar="EXPERIMENT")
@_task_option(default=None)
@click.option("--config", "config_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="rl-zoo-style YAML keyed by task (its section named by the task's config_key, its name; a task "
                   "of your own passes its own YAML)  [default: the task's file in zoo_configs/ of the source tree: "
                   "memret_ppo.yml for the drawer, memret_ppo_mikasa.yml for MIKASA's tasks]")
@click.option("--controller", default=None,
              help="Frozen controller the memory serves ('scripted': the task's expert; 'learned': its camera-reading "
                   "policy, with --render-backend cpu)" + TASK_CONTROLLER + "; a resumed run keeps its own.")
@click.option("--n-envs", type=click.IntRange(min=1), default=None,
              help="Parallel envs; a round holds n_envs x n_steps decisions, so with many envs give the config "
                   "calibration_coef: 1.0 or fewer n_steps (README: 16 envs)  [default: config]")
@click.option("--timesteps", type=click.IntRange(min=1), default=None, help="Decisions in all  [default: config]")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Run folder  [default: runs/<experiment>-seed<seed>, runs/<experiment>-<task>-seed<seed> for "
                   "another task than the drawer]")
@click.option("--resume", is_flag=True, help="Continue the run in --out from its last checkpoint.")
@click.option("--retriever-from", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="Start the retriever from this model file's (e.g. a run of another benchmark task); the "
                   "retention critic starts fresh.")
@click.option("--eval-episodes", type=click.IntRange(min=1), default=50, show_default=True,
              help="Held-out episodes per evaluation.")
@click.option("--eval-every", type=click.IntRange(min=1), default=5, show_default=True,
              help="Evaluate every N rounds (and at the end).")
@click.option("--progress/--no-progress", default=True, show_default=True,
              help="Show a progress bar (without it, SB3 prints every round's statistics).")
@_render_backend_option
@_physics_options
@click.pass_context
def train(ctx: click.Context, experiment: str, task: str | None, config_path: Path | None, controller: str,
          n_envs: int | None, timesteps: int | None, seed: int, out: Path | None, resume: bool,
          retriever_from: Path | None, eval_episodes: int, eval_every: int, progress: bool, render_backend: str,
          backend: str, ray_address: str | None) -> None:
    """Train the retriever and retention networks with PPO on EXPERIMENT (recall: what the task's controller
    must know, the drawer's layer or a cue's colour, reaches it only through a retrieved memory)."""
    from sb3_memret.tasks import make_task
    from sb3_memret.training import RunOptions, format_history, load_run_config, start_retriever, train as run_training
    from sb3_memret.workers import exit_status

    name = task or DEFAULT_TASK
    out = out or Path("runs") / (f"{experiment}-seed{seed}" if name == DEFAULT_TASK else f"{experiment}-{name}-seed{seed}")
    if resume and (out / "config.yml").exists():
        saved = load_run_config(out).env_kwargs.get("task", DEFAULT_TASK)
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
    controller = controller or (_run_controller(out, name) if resume else the_task.default_controller)
    built = _controller(ctx, None, controller, name)
    # a controller that reads cameras gets the software renderer unless a backend is named
    render_backend = render_backend or _render_backend(ctx, None, "cpu" if built.spec.needs_images
                                                       else the_task.default_render_backend)
    options = RunOptions(out=out, controller=controller, seed=seed, resume=resume, retriever_from=retriever_from,
                         eval_episodes=eval_episodes, eval_every=eval_every, eval_seed=HELD_OUT_SEED, progress_bar=progress,
                         render_backend=render_backend, backend=backend, ray_address=ray_address,
                         # the bar and the closing table say enough; without the bar, SB3's per-round dumps
                         log_formats=("csv", "tensorboard") if progress else ("stdout", "csv", "tensorboard"))
    if retriever_from is not None:
        try:
            start_retriever(config, options)
        except ValueError as err:
            raise click.BadParameter(str(err), param_hint="--retriever-from") from err
    try:
        result = run_training(config, options, built)
    except (FileExistsError, FileNotFoundError) as err:
        raise click.UsageError(str(err)) from err
    click.echo(format_history(result.history))
    click.echo(f"\n{result.num_timesteps} decisions, {result.rounds} rounds in {result.wall_seconds / 60:.1f} min; "
               f"run folder {result.out}")
    if result.interrupted:
        click.echo(f"stopped by {result.stopped_by}: saved {result.model_path}; continue with "
                   f"sb3-memret train {experiment} --out {result.out} --resume", err=True)
        sys.exit(exit_status(result.stopped_by))
    click.echo(f"model: {result.model_path} (load with stable_baselines3.PPO.load)")
    click.echo(f"report: sb3-memret report {result.out}")


@main.command()
@click.argument("experiment", type=click.Choice(list(EXPERIMENTS)), metavar="EXPERIMENT")
@_task_option()
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
@_render_backend_option
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
    from sb3_memret.tuning import BEST_CONFIG, TRIALS_FILE, TuneOptions, tune as run_tune
    from sb3_memret.workers import exit_status

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
    controller = controller or _default_controller(task)
    built = _controller(ctx, None, controller, task)
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


@main.command("eval")
@click.argument("model_path", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@_task_option(default=None)
@click.option("--condition", type=click.Choice(["recall", "oracle", "none"]), default="recall", show_default=True,
              help="recall: the layer only via retrieved memory; oracle: in the instruction; none: bare instruction.")
@click.option("--episodes", type=click.IntRange(min=1), default=50, show_default=True, help="Held-out episodes.")
@click.option("--controller", default=None,
              help="Frozen controller the memory serves ('scripted': the run's task's expert)." + RUN_CONTROLLER)
@click.option("--n-envs", type=click.IntRange(min=1), default=1, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=HELD_OUT_SEED, show_default=True,
              help="Seed of the evaluation episodes (training never uses it).")
@click.option("--stochastic", is_flag=True, help="Sample retrievals instead of acting greedily.")
@click.option("--objects", type=click.Choice(sorted(OBJECT_SETS)), default=None,
              help="Object set the episodes hide (heldout: objects no training episode had)  [default: the run's]")
@click.option("--retention", type=click.Choice(list(RETENTION_RULES)), default=None,
              help="What evicts: the learned critic or a fixed rule (fifo, lru, prior)  [default: the run's]")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON on stdout.")
@_render_backend_option
@_physics_options
@click.pass_context
def evaluate(ctx: click.Context, model_path: Path, task: str | None, condition: str, episodes: int, controller: str, n_envs: int, seed: int,
             stochastic: bool, objects: str | None, retention: str | None, as_json: bool, render_backend: str,
             backend: str, ray_address: str | None) -> None:
    """Evaluate a trained model: success per group (the drawer's layer, the cue's colour) and retrieval
    accuracy, at the task's protocol seeds where it has them (MIKASA's 4242424242 + i)."""
    from sb3_memret.evaluation import evaluate_retrieval
    from sb3_memret.envs.vec_env import make_recall_vec_env
    from sb3_memret.training import eval_env_kwargs

    from sb3_memret.tasks import make_task

    model, = _load_models([model_path], "MODEL_PATH")
    kwargs = eval_env_kwargs(model, model_path, condition, controller, render_backend)
    if task is not None and task != kwargs.get("task", DEFAULT_TASK):
        raise click.BadParameter(f"{str(model_path)!r} was trained on task {kwargs.get('task', DEFAULT_TASK)!r}, "
                                 f"not {task!r}", param_hint="--task")
    controller = controller or _run_controller(_model_run(model_path), kwargs.get("task", DEFAULT_TASK))
    kwargs["controller"] = _controller(ctx, None, controller, kwargs.get("task"))
    kwargs["render_backend"] = render_backend or _render_backend(
        ctx, None, "cpu" if kwargs["controller"].spec.needs_images
        else make_task(kwargs.get("task", DEFAULT_TASK)).default_render_backend)
    if objects is not None:
        kwargs["objects"] = objects
    if retention is not None:
        kwargs["retention"] = retention
    venv = make_recall_vec_env(n_envs, kwargs, backend=backend, ray_address=ray_address)
    try:
        with click.progressbar(length=episodes, label=f"{condition} evaluation", file=sys.stderr) as bar:
            report = evaluate_retrieval(model, venv, episodes, seed=seed, deterministic=not stochastic,
                                        on_episode=lambda _: bar.update(1))
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
    click.echo(f"| {'layer' if kwargs.get('task', DEFAULT_TASK) == DEFAULT_TASK else 'group'} | episodes | success |")
    click.echo("|---|---|---|")
    for key in list(report.episodes_per_group) + ["overall"]:
        count = report.episodes if key == "overall" else report.episodes_per_group[key]
        click.echo(f"| {key} | {count} | {report.success[key]:.0%} |")
    if report.needed_fact_gone_rate is not None:
        click.echo(f"before each task, the long-term store kept the target's true fact in {report.target_fact_kept_rate:.0%} "
                   f"of tasks, a stale one in {report.stale_fact_kept_rate:.0%}; needed fact gone (seen since the "
                   f"last move, not kept): {report.needed_fact_gone_rate:.0%}")


@main.command()
@click.argument("ablation", type=click.Choice(["replan", "prompt", "memcount", "wording"]))
@_task_option()
@click.option("--controller", default=None, callback=_controller_spec,
              help="Frozen controller to characterise." + TASK_CONTROLLER)
@click.option("--episodes", type=click.IntRange(min=1), default=17, show_default=True, help="Episodes per cell.")
@click.option("--seed", type=click.IntRange(min=0), default=HELD_OUT_SEED, show_default=True,
              help="First placement seed; every cell plays the same placements.")
@click.option("--n-envs", type=click.IntRange(min=1), default=os.cpu_count() or 1, show_default=True,
              help="Envs played in parallel (all served by one controller).")
@click.option("--layer", type=click.IntRange(min=min(LAYERS), max=max(LAYERS)), default=2, show_default=True,
              help="prompt: the cube's drawer layer.")
@click.option("--intervals", default=",".join(map(str, (5, 8, 10, 12, 16, 20, 24, 28, 32))), show_default=True,
              help="replan: comma-separated replan intervals.")
@click.option("--replan-every", type=click.IntRange(min=1), default=None,
              help="prompt, memcount: control steps executed per action chunk  [default: the drawer's, 8]")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Also write <ablation>.md, .csv and .json into this folder.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON on stdout instead of the table.")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
@_render_backend_option
@_physics_options
@click.pass_context
def ablate(ctx: click.Context, ablation: str, task: str, controller: str, episodes: int, seed: int, n_envs: int, layer: int,
           intervals: str, replan_every: int | None, out: Path | None, as_json: bool, progress: bool,
           render_backend: str, backend: str, ray_address: str | None) -> None:
    """Characterise how a frozen controller consumes memory: ABLATION is replan (success per layer
    per replan interval, oracle memory), prompt (object word x layer number) or memcount (zero, one
    or two memories) or wording (the oracle memory reworded as no training prompt was; these
    cells alone waive the prompt contract). These are the drawer's ablations (its layers and wordings);
    another task's prompt conditions are `rollout --task T --condition oracle|none|wrong --replan-every N`."""
    if task != DEFAULT_TASK:
        raise click.BadParameter(f"the ablations vary the drawer's layers and wordings; for task {task!r} compare "
                                 "prompt conditions and replan intervals with `sb3-memret rollout --task "
                                 f"{task} --condition oracle|none|wrong --replan-every N`", param_hint="--task")
    from sb3_memret.analysis.ablations import (memcount_ablation, prompt_ablation, replan_ablation, run_ablation,
                                      wording_ablation)
    from sb3_memret.tasks import make_task

    chunk_len = ctx.meta["controller"].spec.chunk_len
    replan_every = replan_every or make_task(task).replan_every
    render_backend = _camera_render_backend(ctx, render_backend, ctx.meta["controller"])
    if ablation == "replan":
        try:
            steps = [int(i) for i in intervals.split(",")]
        except ValueError:
            raise click.BadParameter(f"{intervals!r} is not a comma-separated list of integers",
                                     param_hint="--intervals") from None
        if not steps or min(steps) < 1 or max(steps) > chunk_len:
            raise click.BadParameter(f"intervals {steps} must lie in [1, {chunk_len}] (the controller's chunk length)",
                                     param_hint="--intervals")
        spec = replan_ablation(steps)
    else:
        if replan_every > chunk_len:
            raise click.BadParameter(f"{replan_every} exceeds the controller's chunk length {chunk_len}",
                                     param_hint="--replan-every")
        specs = {"prompt": lambda: prompt_ablation(layer, replan_every), "memcount": lambda: memcount_ablation(replan_every),
                 "wording": lambda: wording_ablation(replan_every)}
        spec = specs[ablation]()
    total = len(spec.cells) * episodes
    with click.progressbar(length=total, label=f"{ablation} ablation ({len(spec.cells)} cells)", file=sys.stderr,
                           hidden=not progress) as bar:
        result = run_ablation(spec, controller, episodes, seed, n_envs, render_backend,
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
    from sb3_memret.training import INITIAL_MODEL

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


@main.command()
@click.argument("models", nargs=-1, required=True, type=click.Path(exists=True, path_type=Path))
@_task_option(default=None)
@click.option("--seed", type=click.IntRange(min=0), default=HELD_OUT_SEED, show_default=True,
              help="Episode whose first decision is traced (the same bank for every model).")
@click.option("--sample-seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the Plackett-Luce draw marked with '*'.")
@click.option("--controller", default=None, callback=_controller_spec,
              help="Frozen controller the memory serves." + RUN_CONTROLLER)
@click.option("--json", "as_json", is_flag=True, help="Print the traces as JSON on stdout.")
@_render_backend_option
def trace(models: tuple[Path, ...], task: str | None, seed: int, sample_seed: int, controller: str, as_json: bool,
          render_backend: str | None) -> None:
    """Show every memory in the bank at the first retrieval step with each model's retriever score
    ('*' = sampled, 'C' = the true memory). MODELS are model files or run folders (a run
    folder traces its untrained and final policies: before and after training)."""
    from sb3_memret.analysis.trace import model_label, trace_models
    from sb3_memret.training import eval_env_kwargs

    paths = _trace_targets(models)
    loaded = list(zip(paths, _load_models(paths, "MODELS")))
    run_task = eval_env_kwargs(loaded[0][1], paths[0], "recall", controller).get("task", DEFAULT_TASK)
    controller = controller or _run_controller(_model_run(paths[0]), run_task)
    render_backend = _run_task(click.get_current_context(), task, run_task, paths[0], controller, render_backend)
    env_kwargs = eval_env_kwargs(loaded[0][1], paths[0], "recall", controller, render_backend)
    traces = trace_models([(model_label(m, p), m) for p, m in loaded], env_kwargs, seed, sample_seed)
    if as_json:
        click.echo(json.dumps([t.to_dict() for t in traces]))
        return
    click.echo(f'instruction: "{traces[0].instruction}"   episode seed {seed}, group {traces[0].group}   '
               f"( * = sampled, C = the true memory )")
    for t in traces:
        click.echo("\n" + t.format())


@main.command()
@click.argument("run", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="PNG to write  [default: RUN/learning_curves.png]")
def plot(run: Path, out: Path | None) -> None:
    """Plot the learning curves of a training run: held-out greedy accuracy and success, training
    sampled fraction, and policy entropy on a second axis."""
    from sb3_memret.analysis.plotting import plot_learning_curves
    from sb3_memret.training import retrieval_chance

    try:
        path = plot_learning_curves(run, out, chance=retrieval_chance(run))
    except (FileNotFoundError, ValueError) as err:
        raise click.UsageError(str(err)) from err
    click.echo(str(path))



@main.command()
@click.argument("run", type=click.Path(exists=True, file_okay=False, path_type=Path))
@_task_option(default=None)
@click.option("--controller", default=None, callback=_controller_spec,
              help="Frozen controller for the baseline evaluations and the trace." + RUN_CONTROLLER)
@click.option("--baseline-episodes", type=click.IntRange(min=0), default=None,
              help="Episodes of the oracle and no-memory baselines (0 skips them)  [default: as the final evaluation]")
@click.option("--n-envs", type=click.IntRange(min=1), default=os.cpu_count() or 1, show_default=True)
@click.option("--trace-seed", type=click.IntRange(min=0), default=None,
              help="Episode of the introspection trace  [default: the run's held-out seed]")
@_render_backend_option
@_physics_options
def report(run: Path, task: str | None, controller: str, baseline_episodes: int | None, n_envs: int,
           trace_seed: int | None, render_backend: str | None, backend: str, ray_address: str | None) -> None:
    """Write RUN/report.md: what was learned, the learning curves, the evaluation tables, the
    baselines, the before/after trace, any saved ablations and the configuration."""
    from sb3_memret.analysis.report import ReportOptions, write_report
    from sb3_memret.training import load_run_config

    if (run / "config.yml").exists():
        run_task = load_run_config(run).env_kwargs.get("task", DEFAULT_TASK)
        controller = controller or _run_controller(run, run_task)
        render_backend = _run_task(click.get_current_context(), task, run_task, run, controller, render_backend)
    controller = controller or _default_controller(task)

    options = ReportOptions(controller, baseline_episodes, n_envs, trace_seed, render_backend, backend, ray_address)
    try:
        path = write_report(run, options, on_progress=lambda step: click.echo(step + " ...", err=True))
    except (FileNotFoundError, ValueError) as err:
        raise click.UsageError(str(err)) from err
    click.echo(str(path))


def _add_command_groups() -> None:
    """The command groups that live in their own modules."""
    from sb3_memret.benchmark.command import benchmark

    main.add_command(benchmark)


_add_command_groups()
