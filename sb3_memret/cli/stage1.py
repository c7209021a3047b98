"""Stage 1's commands: ``demos`` (expert demonstrations), ``finetune`` (a controller from them) and ``serve`` (a controller over the network)."""

from __future__ import annotations

import os
from pathlib import Path

import click

from sb3_memret.cli.options import DEFAULT_TASK, ConvList, build_controller, render_backend_option, task_option
from sb3_memret.tasks.drawer.cabinet import LAYERS
from sb3_memret.tasks.drawer.objects import OBJECT_SETS
from sb3_memret.common.seeds import DEMO_SEED


@click.command()
@task_option()
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
@click.option("--max-steps", type=click.IntRange(min=1), default=None,
              help="Control steps an episode lasts at most (an expert whose prompt lacks a fact it needs may hold "
                   "still to the end: a shorter limit spares those frames)  [default: the task's own]")
@click.option("--image-size", type=click.IntRange(min=16, max=224), default=None,
              help="Store camera images resized to this square size  [default: 224 drawer, 128 MIKASA]")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
@render_backend_option
def demos(task: str, episodes: int, out: Path, seed: int, noise: float, noisy_fraction: float, learner: str | None,
          n_envs: int, objects: str, n_objects: int, replan_every: int | None, frames: str | None,
          max_steps: int | None, image_size: int | None, progress: bool, render_backend: str) -> None:
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
            build_controller(click.get_current_context(), None, learner, task)
        _task_demos(task, episodes, out, seed, noise, noisy_fraction, n_envs, replan_every, progress,
                    render_backend, frames, learner, max_steps)
        return
    from sb3_memret.stage1.demos import plan_episodes, record_demos
    from sb3_memret.tasks.drawer import DrawerTask

    if learner is not None:
        build_controller(click.get_current_context(), None, learner)
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
                     image_size=image_size or 224, max_steps=max_steps)
    click.echo(f"{episodes} episodes ({wins} successful) written to {out}")


def _task_demos(task: str, episodes: int, out: Path, seed: int, noise: float, noisy_fraction: float, n_envs: int,
                replan_every: int | None, progress: bool, render_backend: str, frames: str, learner: str | None,
                max_steps: int | None) -> None:
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
                              n_envs, replan_every, on_episode=on_episode, frames=frames, learner=learner,
                              max_steps=max_steps)
        except (NotImplementedError, ValueError) as err:
            raise click.UsageError(str(err)) from err
    click.echo(f"{episodes} episodes ({wins} successful) written to {out}")


@click.command()
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
@task_option()
@click.option("--tasks", "dataset_tasks", default=None, metavar="LIST",
              help="learned: each DATASET's task, a comma list in their order, for one policy over several tasks "
                   "(it reads proprioception and cameras; each task's perception loss covers its own entries).")
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
@click.option("--image-head", type=ConvList(), default="32x3", show_default=True,
              help="learned, efficientnet_lite0: the convs each camera head runs on the trunk's maps before its "
                   "keypoints, CHANNELSxKERNEL comma-separated (e.g. 64x3,64x1 to tell apart more objects alike).")
@click.option("--trunk-stride", type=click.Choice(["8", "4"]), default="8", show_default=True,
              help="learned, efficientnet_lite0: where the frozen trunk is cut: its maps are 1/stride of the picture's "
                   "side (4: 32x32 maps at 128x128, shallower features, for objects a few pixels wide).")
@click.option("--trunk-scale", type=click.Choice(["1", "2"]), default="1", show_default=True,
              help="learned, efficientnet_lite0: the picture is enlarged this many times before the frozen trunk "
                   "(2: 32x32 maps of the full trunk at 128x128, four times its cost).")
@click.option("--image-colour/--no-image-colour", default=False, show_default=True,
              help="learned, efficientnet_lite0: the camera heads also read the image's colour on the trunk's grid "
                   "(for objects told apart by hue alone).")
@click.option("--image-film/--no-image-film", default=False, show_default=True,
              help="learned: the camera heads' keypoints are conditioned on the prompt (FiLM), to find the object it "
                   "names among many alike.")
@click.option("--pointer/--no-pointer", default=False, show_default=True,
              help="learned: the action head also reads the perceived entries of the object the prompt points at "
                   "(attention over the perceived objects, named <object>_x/_y/_z/_visible), for scenes of many alike.")
@click.option("--perception-state/--no-perception-state", default=False, show_default=True,
              help="learned: the perception head also reads the state (the hand's pose) through a hidden layer: "
                   "where an object lies in the wrist camera's picture says where it is only with where the hand is.")
@click.option("--pointer-hindsight", type=click.FloatRange(min=0.0), default=0.0, show_default=True,
              help="learned, with --pointer: weight of a cross-entropy that points each training prompt at the object "
                   "its demonstrations' hands end nearest (0: the pointer learns from the action loss alone).")
@click.option("--cache-features/--no-cache-features", default=True, show_default=True,
              help="learned, with a frozen trunk: keep each dataset's trunk features on disk ($SB3_MEMRET_CACHE, else "
                   "~/.cache/sb3-memret) and read them back in later finetunes of the same frames.")
@click.option("--resume", is_flag=True, default=False,
              help="learned: go on from the unfinished finetune in OUT (its state at the last logged step), on the "
                   "same datasets and options.")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
def finetune(datasets: tuple[Path, ...], out: Path, policy: str, steps: int | None, batch_size: int | None,
             learning_rate: float | None, seed: int, pretrained: Path | None, tokenizer: Path | None, lora_rank: int,
             device: str, task: str, dataset_tasks: str | None, state: str | None, image_encoder: str,
             image_dim: int, keypoints: int, image_head: tuple[tuple[int, int], ...], trunk_stride: str,
             trunk_scale: str, image_colour: bool, image_film: bool, pointer: bool, perception_state: bool,
             pointer_hindsight: float, cache_features: bool, resume: bool, progress: bool) -> None:
    """Train a frozen controller from DATASETS (LeRobotDatasets written by `sb3-memret demos`).

    The learned policy reads the prompt as frozen MiniLM per-token features, the state (and the
    cameras when the datasets have them) and predicts a 32 x 7 action chunk; the checkpoint
    (config.json + model.safetensors) loads as --controller learned:OUT. pi05 writes OUT/checkpoint
    and OUT/adapter, which load as --controller 'lerobot:OUT/checkpoint?adapter=OUT/adapter'.
    """
    from tqdm import tqdm

    if policy == "pi05":
        if resume:
            raise click.BadParameter("--resume goes on from a learned policy's finetune; --policy pi05 starts afresh",
                                     param_hint="--resume")
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
    from sb3_memret.controllers.learned.vision import TRUNK_HEAD, TRUNK_STRIDE
    from sb3_memret.stage1.datasets import has_cameras
    from sb3_memret.stage1.finetune import FinetuneSettings, tasks_template
    from sb3_memret.stage1.finetune import finetune as train_policy
    from sb3_memret.tasks import make_task

    settings = FinetuneSettings(steps=steps or 8000, batch_size=batch_size or 256,
                                learning_rate=learning_rate or 1e-3, seed=seed, pointer_hindsight=pointer_hindsight)
    if pointer_hindsight > 0 and not pointer:
        raise click.BadParameter(f"--pointer-hindsight {pointer_hindsight} trains the pointer: add --pointer",
                                 param_hint="--pointer-hindsight")
    by_task = paired_datasets(datasets, dataset_tasks, task) if dataset_tasks is not None else None
    tasks = [make_task(name) for name in by_task] if by_task else [make_task(task)]
    template = tasks_template(tasks)
    chunk_lens = {t.name: t.expert().spec.chunk_len for t in tasks}
    if len(set(chunk_lens.values())) > 1:
        raise click.BadParameter(f"the tasks' experts act in chunks of different lengths {chunk_lens}; one policy "
                                 "predicts one chunk length", param_hint="--tasks")
    if image_encoder == "cnn" and image_head != TRUNK_HEAD:
        raise click.BadParameter(f"--image-head shapes a frozen trunk's camera heads; --image-encoder cnn has convs "
                                 "of its own", param_hint="--image-head")
    if image_encoder == "cnn" and (int(trunk_stride) != TRUNK_STRIDE or int(trunk_scale) != 1):
        raise click.BadParameter(f"--trunk-stride {trunk_stride} and --trunk-scale {trunk_scale} shape a frozen "
                                 "trunk; --image-encoder cnn has strides of its own", param_hint="--trunk-stride")
    try:
        config = LearnedPolicyConfig(instructions=template.instructions, fact_templates=template.fact_templates,
                                     image_encoder=image_encoder, image_dim=image_dim, keypoints=keypoints,
                                     image_head=image_head, trunk_stride=int(trunk_stride),
                                     trunk_scale=int(trunk_scale), image_colour=image_colour, image_film=image_film,
                                     pointer=pointer, perception_state=perception_state,
                                     chunk_len=chunk_lens[tasks[0].name])
    except ValueError as err:
        raise click.BadParameter(str(err)) from err
    try:
        state = state or ("proprio" if has_cameras(datasets) else "full")
    except (FileNotFoundError, ValueError) as err:
        raise click.UsageError(str(err)) from err
    with tqdm(total=settings.steps, desc="finetune learned", disable=not progress) as bar:
        def on_step(step: int, loss: float) -> None:
            bar.update(step - bar.n)  # a resumed run starts past 0
            if step % 100 == 0:
                bar.set_postfix(loss=f"{loss:.4f}")

        try:
            train_policy(by_task or datasets, out, config, settings=settings, on_step=on_step,
                         task=None if by_task else task, state=state, cache_features=cache_features,
                         resume=resume)
        except (FileNotFoundError, FileExistsError, ValueError) as err:
            raise click.UsageError(str(err)) from err
    click.echo(f"checkpoint written: --controller learned:{out}")


def paired_datasets(datasets: tuple[Path, ...], dataset_tasks: str, task: str) -> dict[str, list[Path]]:
    """``--tasks``: each task's datasets, in the order given, or a BadParameter naming what does not pair."""
    names = [name.strip() for name in dataset_tasks.split(",")]
    if len(names) != len(datasets):
        raise click.BadParameter(f"{len(names)} tasks for {len(datasets)} datasets: name each DATASET's task, in order",
                                 param_hint="--tasks")
    if task != DEFAULT_TASK:
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

