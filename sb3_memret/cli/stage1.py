"""Stage 1's commands: ``demos`` (expert demonstrations), ``finetune`` (a controller from them) and ``serve`` (a controller over the network)."""

from __future__ import annotations

import os
from pathlib import Path

import click

from sb3_memret.cli.options import build_controller, render_backend_option, task_option
from sb3_memret.common.seeds import DEMO_SEED


@click.command()
@task_option()
@click.option("--episodes", type=click.IntRange(min=1), default=240, show_default=True, help="Episodes to record.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="New folder for the LeRobotDataset.")
@click.option("--seed", type=click.IntRange(min=0), default=DEMO_SEED, show_default=True,
              help="First env seed (episodes use seed..seed+episodes-1).")
@click.option("--noise", type=click.FloatRange(min=0.0), default=0.05, show_default=True,
              help="Std of the Gaussian noise added to the executed arm actions of noisy episodes (labels stay clean).")
@click.option("--noisy-fraction", type=click.FloatRange(0.0, 1.0), default=0.5, show_default=True,
              help="Share of episodes played with action noise.")
@click.option("--learner", default=None,
              help="DAgger round: this controller (e.g. learned:PATH) acts while the expert labels every frame.")
@click.option("--n-envs", type=click.IntRange(min=1), default=os.cpu_count() or 1, show_default=True,
              help="Worker processes.")
@click.option("--objects", default=None,
              help="The task's objects, for a task that takes them (the drawer: a named set such as train; its "
                   "targets cycle over them and the prompts name them)  [default: the task's]")
@click.option("--n-objects", type=click.IntRange(min=1), default=None,
              help="Objects per episode, for a task that takes them (the drawer: one per drawer)  [default: the "
                   "task's]")
@click.option("--replan-every", type=click.IntRange(min=1), default=None,
              help="Control steps executed from each expert chunk  [default: the task's (Task.replan_every): 8 on the "
                   "drawer, 4 on MIKASA's short episodes]")
@click.option("--frames", type=click.Choice(["every", "decisions"]), default=None,
              help="Keep every control step (pi05 finetuning reads chunks from consecutive frames) or only the "
                   "decision steps, each with its chunk of labels, rendering the cameras only there  "
                   "[default: decisions with a render backend, else every]")
@click.option("--max-steps", type=click.IntRange(min=1), default=None,
              help="Control steps an episode lasts at most (an expert whose prompt lacks a fact it needs may hold "
                   "still to the end: a shorter limit spares those frames)  [default: the task's own]")
@click.option("--image-size", type=click.IntRange(min=16), default=None,
              help="Store camera images resized to this square size, at most the size they render at  [default: as "
                   "rendered: 224 on the drawer, 128 on MIKASA]")
@click.option("--prompt-mix", default="bare=0.2,matching=0.6,mismatched=0.2", show_default=True,
              metavar="KIND=SHARE,...",
              help="Shares of the episodes' prompt kinds: bare, matching (the true facts), mismatched (facts naming "
                   "something else), recalled (a decoy until the writer has read the true facts, then those, as the "
                   "recall condition's memory gives them); a kind left out has none.")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
@render_backend_option
def demos(task: str, episodes: int, out: Path, seed: int, noise: float, noisy_fraction: float, learner: str | None,
          n_envs: int, objects: str | None, n_objects: int | None, replan_every: int | None, frames: str | None,
          max_steps: int | None, image_size: int | None, prompt_mix: str, progress: bool, render_backend: str) -> None:
    """Record the task's scripted expert as a LeRobotDataset (v3.0) for finetuning.

    \b
    Per frame: the task's state (the drawer's 19: end-effector state, drawer openings, cube
    detection, zero until the cube's drawer is open; MIKASA's: joints, hand pose, the object
    detector), action (the expert's 7-D end-effector delta pose), task (the exact prompt), and with
    --render-backend cpu|gpu the two cameras as observation.images.image / .wrist_image.

    \b
    Prompts in the data (--prompt-mix): the bare instruction in 20% of episodes, the task's true
    fact in 60% ("pick out the cube. the cube is in drawer layer L.", "... the cue cube was red.")
    and a fact naming something else in 20% (the drawer's expert opens the named drawer, finds it
    empty and holds still); recalled prompts carry a decoy ("the fork blinked twice.") until the
    writer has read the true fact, then that fact. The drawer's episodes cycle over its layers
    and, with --objects train --n-objects 3, over its objects ("pick out the tin. the tin is in
    drawer layer L."). Kept out, so they stay held-out tests: two-memory prompts, other objects'
    and holding facts, and paraphrases. Off the expert's path: --noisy-fraction of the episodes run with --noise on the
    arm (clean labels), and --learner makes a DAgger round. Ctrl-C keeps every episode saved so far.
    """
    from tqdm import tqdm

    from sb3_memret.stage1.demos import record_demos
    from sb3_memret.tasks import make_task
    from sb3_memret.tasks.demos import PromptMix

    if out.exists():
        raise click.BadParameter(f"{str(out)!r} already exists; demonstrations go to a new folder", param_hint="--out")
    try:
        mix = PromptMix.parse(prompt_mix)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="--prompt-mix") from None
    frames = frames or ("every" if render_backend == "none" else "decisions")
    the_task = make_task(task)
    for name, value in (("objects", objects), ("n_objects", n_objects)):
        if value is not None:
            try:
                the_task = the_task.with_options(**{name: value})
            except ValueError as err:
                raise click.BadParameter(str(err), param_hint=f"--{name.replace('_', '-')}") from None
    if learner is not None:
        build_controller(click.get_current_context(), None, learner, task)
    try:
        planned = the_task.plan_demos(episodes, seed, noise, noisy_fraction, mix)
    except (NotImplementedError, ValueError) as err:
        raise click.UsageError(str(err)) from err
    wins = 0
    with tqdm(total=episodes, desc=f"{the_task.name} demonstrations", unit="episode", disable=not progress) as bar:
        def on_episode(recorded) -> None:
            nonlocal wins
            wins += recorded.success
            bar.update(1)
            bar.set_postfix(success=f"{wins}/{bar.n}")

        try:
            record_demos(out, the_task, planned, render_backend, n_envs, replan_every, on_episode=on_episode,
                         frames=frames, learner=learner, max_steps=max_steps, image_size=image_size)
        except (NotImplementedError, ValueError) as err:
            raise click.UsageError(str(err)) from err
    click.echo(f"{episodes} episodes ({wins} successful) written to {out}")


@click.command()
@click.argument("datasets", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True, help="Checkpoint folder.")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="The finetune's recipe: policy, inputs, network and optimisation (a shipped controller's is its "
                   "checkpoint's recipe.yml)  [default: zoo_configs/finetune_learned.yml, or finetune_pi05.yml with "
                   "--policy pi05]")
@click.option("--policy", type=click.Choice(["learned", "pi05"]), default=None,
              help="learned: the project's small policy (CPU, minutes); pi05: LoRA on lerobot's PI05  [default: the "
                   "recipe's]")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Change one key of the recipe, dotted into its sections (e.g. training.steps=4000, "
                   "model.pointer=true, pi05.pretrained=PATH); repeatable.")
@task_option()
@click.option("--tasks", "dataset_tasks", default=None, metavar="LIST",
              help="learned: each DATASET's task, a comma list in their order, for one policy over several tasks "
                   "(it reads proprioception and cameras; each task's perception loss covers its own entries).")
@click.option("--resume", is_flag=True, default=False,
              help="learned: go on from the unfinished finetune in OUT (its state at the last logged step), on the "
                   "same datasets and recipe.")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
def finetune(datasets: tuple[Path, ...], out: Path, config_path: Path | None, policy: str | None,
             overrides: tuple[str, ...], task: str, dataset_tasks: str | None, resume: bool, progress: bool) -> None:
    """Train a frozen controller from DATASETS (LeRobotDatasets written by `sb3-memret demos`) by a recipe file.

    The learned policy reads the prompt as frozen MiniLM per-token features, the state (and the
    cameras when the datasets have them) and predicts a 32 x 7 action chunk; the checkpoint
    (config.json + model.safetensors) loads as --controller learned:OUT. pi05 writes OUT/checkpoint
    and OUT/adapter, which load as --controller 'lerobot:OUT/checkpoint?adapter=OUT/adapter'.
    """
    from sb3_memret.stage1.finetune_config import load_recipe

    try:
        recipe = load_recipe(config_path, policy or "learned", overrides)
    except (FileNotFoundError, ValueError) as err:
        raise click.BadParameter(str(err), param_hint="--set" if overrides else "--config") from None
    if policy is not None and policy != recipe.policy:
        raise click.BadParameter(f"--policy {policy} but the recipe {str(config_path)!r} is policy {recipe.policy!r}",
                                 param_hint="--policy")
    if recipe.policy == "pi05":
        _finetune_pi05(recipe, datasets, out, task, resume, progress)
        return
    _finetune_learned(recipe, datasets, out, task, dataset_tasks, resume, progress)


def _finetune_pi05(recipe, datasets: tuple[Path, ...], out: Path, task: str, resume: bool, progress: bool) -> None:
    """``finetune`` with a pi05 recipe: LoRA on lerobot's PI05, on one dataset of ``task``."""
    from tqdm import tqdm

    from sb3_memret.stage1.finetune import tasks_template
    from sb3_memret.stage1.finetune_pi05 import finetune_pi05
    from sb3_memret.tasks import make_task

    if resume:
        raise click.BadParameter("--resume goes on from a learned policy's finetune; policy pi05 starts afresh",
                                 param_hint="--resume")
    pi05, training = recipe.pi05, recipe.training
    if pi05.pretrained is None:
        raise click.BadParameter("policy pi05 needs its pretrained PI05 checkpoint folder: --set "
                                 "pi05.pretrained=PATH", param_hint="--set")
    if len(datasets) != 1:
        raise click.BadParameter(f"policy pi05 trains on one dataset, got {len(datasets)}", param_hint="DATASETS")
    with tqdm(total=training.steps, desc="finetune pi05 (LoRA)", disable=not progress) as bar:
        finetune_pi05(datasets[0], pi05.pretrained, out, steps=training.steps, batch_size=training.batch_size,
                      learning_rate=training.learning_rate, lora_rank=pi05.lora_rank, device=pi05.device,
                      tokenizer=pi05.tokenizer, seed=training.seed, on_step=lambda step, loss: bar.update(1),
                      prompt_template=tasks_template([make_task(task)]))
    tok = f"&tokenizer={pi05.tokenizer}" if pi05.tokenizer is not None else ""
    click.echo(f"LoRA adapter written: --controller 'lerobot:{out}/checkpoint?adapter={out}/adapter{tok}'")


def _finetune_learned(recipe, datasets: tuple[Path, ...], out: Path, task: str, dataset_tasks: str | None,
                      resume: bool, progress: bool) -> None:
    """``finetune`` with a learned recipe: the project's policy on DATASETS of ``task``, or of each task
    ``dataset_tasks`` names."""
    from tqdm import tqdm

    from sb3_memret.controllers.learned import LearnedPolicyConfig
    from sb3_memret.stage1.datasets import has_cameras
    from sb3_memret.stage1.finetune import finetune as train_policy
    from sb3_memret.stage1.finetune import tasks_template
    from sb3_memret.tasks import make_task

    task_given = click.get_current_context().get_parameter_source("task") != click.core.ParameterSource.DEFAULT
    by_task = paired_datasets(datasets, dataset_tasks, task if task_given else None) if dataset_tasks else None
    tasks = [make_task(name) for name in by_task] if by_task else [make_task(task)]
    template = tasks_template(tasks)
    chunk_lens = {t.name: t.expert().spec.chunk_len for t in tasks}
    if len(set(chunk_lens.values())) > 1:
        raise click.BadParameter(f"the tasks' experts act in chunks of different lengths {chunk_lens}; one policy "
                                 "predicts one chunk length", param_hint="--tasks")
    try:
        config = LearnedPolicyConfig(instructions=template.instructions, fact_templates=template.fact_templates,
                                     chunk_len=chunk_lens[tasks[0].name], **recipe.policy_options())
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="--config") from None
    try:
        state = recipe.state or ("proprio" if recipe.cameras and has_cameras(datasets) else "full")
    except (FileNotFoundError, ValueError) as err:
        raise click.UsageError(str(err)) from err
    with tqdm(total=recipe.training.steps, desc="finetune learned", disable=not progress) as bar:
        def on_step(step: int, loss: float) -> None:
            bar.update(step - bar.n)  # a resumed run starts past 0
            if step % 100 == 0:
                bar.set_postfix(loss=f"{loss:.4f}")

        try:
            train_policy(by_task or datasets, out, config, settings=recipe.training, on_step=on_step,
                         task=None if by_task else task, state=state, cameras=recipe.cameras,
                         cache_features=recipe.cache_features, resume=resume)
        except (FileNotFoundError, FileExistsError, ValueError) as err:
            raise click.UsageError(str(err)) from err
    click.echo(f"checkpoint written: --controller learned:{out}")


def paired_datasets(datasets: tuple[Path, ...], dataset_tasks: str, task: str | None) -> dict[str, list[Path]]:
    """``--tasks``: each task's datasets, in the order given, or a BadParameter naming what does not pair (``task``:
    a ``--task`` given beside it)."""
    names = [name.strip() for name in dataset_tasks.split(",")]
    if len(names) != len(datasets):
        raise click.BadParameter(f"{len(names)} tasks for {len(datasets)} datasets: name each DATASET's task, in order",
                                 param_hint="--tasks")
    if task is not None:
        raise click.BadParameter(f"--tasks names each dataset's task; --task {task} cannot be given with it",
                                 param_hint="--task")
    from sb3_memret.tasks import check_task_name

    by_task: dict[str, list[Path]] = {}
    for name, root in zip(names, datasets):
        try:
            by_task.setdefault(check_task_name(name), []).append(root)
        except ValueError as err:
            raise click.BadParameter(str(err), param_hint="--tasks") from err
    if len(by_task) < 2:
        raise click.BadParameter(f"--tasks names one task ({names[0]}): use --task for a policy of one task",
                                 param_hint="--tasks")
    return by_task


@click.command()
@click.argument("controller", metavar="CONTROLLER")
@task_option()
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on: the loopback reaches this machine alone; any other needs --api-key.")
@click.option("--port", type=click.IntRange(1, 65535), default=8000, show_default=True)
@click.option("--api-key", envvar="SB3_MEMRET_SERVE_API_KEY", show_envvar=True, default=None,
              help="Key a client must send (`Authorization: Api-Key KEY`, as openpi's client sends its api_key); "
                   "refused at the handshake otherwise. Prefer the environment variable: a command line is public.")
def serve(controller: str, task: str, host: str, port: int, api_key: str | None) -> None:
    """Serve the frozen CONTROLLER (as --controller takes it) over openpi's websocket protocol, with
    openpi's own server: `--controller openpi://HOST:PORT` then runs it from any command. It listens on
    the loopback unless given --host, which then needs an API key. A message larger than any valid
    request is refused unread, a prompt longer than any the project builds before it is parsed. One
    Ctrl-C or SIGTERM stops it: open connections close once any inference in progress has replied."""
    try:
        from sb3_memret.stage1.serve import ControllerPolicy, check_exposure, serve as serve_policy
    except ImportError as err:
        raise click.UsageError(str(err)) from err
    try:
        check_exposure(host, api_key)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="--host" if api_key is None else "--api-key") from err
    try:
        policy = ControllerPolicy(controller, task)
    except (ValueError, OSError, ImportError, RuntimeError) as err:
        raise click.BadParameter(str(err), param_hint="CONTROLLER") from err
    keyed = "; API key required" if api_key is not None else ""
    click.echo(f"serving {controller} on ws://{host}:{port} (openpi protocol{keyed}; Ctrl-C stops)", err=True)
    try:
        serve_policy(policy, host, port, api_key)
    except OSError as err:  # it could not listen there (the port is taken, say)
        raise click.BadParameter(f"cannot serve on {host}:{port}: {err.strerror or err}", param_hint="--port") from err
