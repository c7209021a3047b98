"""One training run of the memory learner: envs, model, callbacks, logs, checkpoints, resume.

A run lives in one folder::

    config.yml              the hyperparameters it was started with (a resume reuses them)
    run.json                how it started: the frozen controller, the seed, the render backend (a resume keeps them)
    progress.csv            one row per round (SB3 logger; a resume appends)
    tensorboard/            the same scalars for tensorboard
    evaluations.jsonl       every held-out evaluation report
    checkpoints/            memret_<timesteps>_steps.zip after each update (and on Ctrl-C / crash)
    best_model.zip          the best held-out policy so far
    initial_model.zip       the untrained policy (round 0), for before/after traces
    final_model.zip         the policy when training ended
    summary.json            wall time and where it went (``seconds``), the last evaluation (a report adds its own
                            time and its baselines)
"""

from __future__ import annotations

import copy
import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import yaml
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_memret.callbacks import (PhaseTimingCallback, RetrievalEvalCallback, RolloutRetrievalCallback,
                                  RoundCheckpointCallback, RunProgressCallback, StopOnRetrievalTarget,
                                  latest_checkpoint)
from sb3_memret.callbacks.checkpoint import checkpoints as list_checkpoints
from sb3_memret.training.config import TrainConfig, parse_section
from sb3_memret.controllers import FrozenController
from sb3_memret.controller_specs import make_controller
from sb3_memret.envs.multi_task import make_decision_vec_env
from sb3_memret.common.errors import RunFolderError
from sb3_memret.common.seeds import HELD_OUT_SEED
from sb3_memret.tasks import make_task, task_in
from sb3_memret.evaluation.retrieval import RetrievalReport
from sb3_memret.policy.networks import HIDDEN
from sb3_memret.policy.policy import MemoryRetrievalPolicy, saved_retriever
from sb3_memret.policy.ppo import MemRetPPO
from sb3_memret.common.run_logger import make_run_logger
from sb3_memret.common.workers import StopRequested, WorkerDiedError, stop_signals_deferred, stop_signals_interrupt

CONFIG_FILE = "config.yml"
RUN_FILE = "run.json"
INITIAL_MODEL = "initial_model.zip"
HISTORY_FILE = "evaluations.jsonl"


@dataclass
class RunOptions:
    """Everything a run needs besides its hyperparameters."""

    out: Path
    controller: str = "scripted"
    seed: int = 0
    resume: bool = False
    eval_episodes: int | None = None  # None: the config's (eval_episodes, else 50)
    eval_every: int | None = None  # None: the config's (eval_every, else 5)
    # None: the config's (initial_eval_episodes, else eval_episodes); never more than eval_episodes
    initial_eval_episodes: int | None = None
    # None: the config's (final_eval_episodes, else eval_episodes); never fewer than eval_episodes
    final_eval_episodes: int | None = None
    eval_seed: int = HELD_OUT_SEED
    progress_bar: bool = False
    log_formats: tuple[str, ...] = ("stdout", "csv", "tensorboard")
    render_backend: str = "none"  # image controllers need "cpu" or "gpu"
    backend: str = "auto"  # where the physics runs (sb3_memret.physics.BACKENDS)
    ray_address: str | None = None  # a Ray cluster for backend "ray"
    retriever_from: Path | None = None  # a new run's retriever starts from this model file's
    # stop once this many held-out evaluations in a row reach this greedy accuracy (None: the config's whole budget)
    stop_at_greedy: float | None = None
    stop_patience: int = 2
    evaluation_listeners: tuple[Any, ...] = ()  # told of every held-out evaluation (RetrievalEvalCallback.listeners)
    # writes a finished run's report while its held-out envs are still open (their workers serve the baselines)
    report: Callable[[RunResult, Any], Path] | None = None
    verbose: int = 0


@dataclass
class RunResult:
    out: Path
    model_path: Path
    num_timesteps: int
    rounds: int
    wall_seconds: float
    stopped_by: str | None = None  # why training stopped early (Ctrl-C, SIGTERM, a dead env worker), if it did
    final: RetrievalReport | None = None
    history: list[dict[str, Any]] = field(default_factory=list)
    # where the wall time went: setup (envs and model), collect (training decisions), update (PPO), evaluate
    seconds: dict[str, Any] = field(default_factory=dict)
    report: Path | None = None  # the report RunOptions.report wrote
    target_reached: int | None = None  # the round RunOptions.stop_at_greedy stopped training at (None: its budget)

    @property
    def interrupted(self) -> bool:
        return self.stopped_by is not None


def stop_reason(err: BaseException) -> str:
    """What stopped a run, in words: 'Ctrl-C', 'SIGTERM', or how an env worker died."""
    if isinstance(err, StopRequested):
        return err.signal_name
    return str(err) if isinstance(err, WorkerDiedError) else "Ctrl-C"


def save_run_config(config: TrainConfig, path: Path) -> None:
    section = {**config.ppo, "policy_kwargs": config.policy_kwargs, "env_kwargs": config.env_kwargs}
    path.write_text(yaml.safe_dump({config.env_id: section}, sort_keys=False))


def load_run_config(out: Path) -> TrainConfig:
    """The validated configuration a run folder saved; a ``RunFolderError`` saying why it cannot be read here."""
    data = yaml.safe_load((out / CONFIG_FILE).read_text())
    (env_id, section), = data.items()
    try:
        return parse_section(section, env_id, where=str(out / CONFIG_FILE))
    except ValueError as err:
        raise RunFolderError(f"the run in {str(out)!r} cannot be read here: {err}") from None


def env_kwargs_for(config: TrainConfig, controller: str, render_backend: str = "none") -> dict[str, Any]:
    """The decision env's arguments: the config's, the controller, and PPO's gamma for the shaping."""
    return {**config.env_kwargs, "controller": controller, "gamma": config.ppo.get("gamma", 0.97),
            "render_backend": render_backend}


def eval_env_kwargs(model: MemRetPPO, model_path: Path, mode: str, controller: str,
                    render_backend: str | None = None) -> dict[str, Any]:
    """Decision-env arguments matching a saved model: its bank size and K from its spaces, the
    rest of the env settings from the run's config.yml when the model sits in a run folder
    (``render_backend`` None: the run's task's default)."""
    kwargs: dict[str, Any] = {}
    for folder in (Path(model_path).parent, Path(model_path).parent.parent):
        if (folder / CONFIG_FILE).exists():
            kwargs = dict(load_run_config(folder).env_kwargs)
            break
    nvec = model.action_space.nvec
    first_task = next(iter(kwargs["tasks"])) if "tasks" in kwargs else task_in(kwargs)
    render_backend = render_backend or make_task(first_task).default_render_backend
    kwargs.update(mode=mode, controller=controller, gamma=model.gamma, k=len(nvec), render_backend=render_backend,
                  observe_potential="potential" in model.observation_space.spaces)
    if not kwargs.get("stores"):  # else each store names its capacity and age unit
        kwargs.update(capacity=int(nvec[0]) - kwargs.get("long_term_capacity", 0), age_unit=model.policy.age_unit)
    return kwargs


def start_retriever(config: TrainConfig | None, options: RunOptions) -> dict[str, Any] | None:
    """The retriever weights a new run starts from (``options.retriever_from``), checked against the
    config's retriever; None to start from scratch."""
    if options.retriever_from is None:
        return None
    if options.resume or config is None:
        raise ValueError("--retriever-from starts a new run; a resumed run continues from its own checkpoint")
    return saved_retriever(options.retriever_from, config.policy_kwargs.get("retriever", "mlp"),
                           config.policy_kwargs.get("hidden", HIDDEN))


def train(config: TrainConfig | None, options: RunOptions, controller: FrozenController | None = None) -> RunResult:
    """Train (or, with ``options.resume``, continue) a run in ``options.out``.

    Ctrl-C, SIGTERM, a dead physics worker or an exception saves a checkpoint before leaving, so
    ``resume`` continues from it; the first three return a result whose ``stopped_by`` says why.
    ``controller`` is the one ``options.controller`` names when the caller has built it already
    (one model in memory, whatever the number of envs).
    """
    began = time.perf_counter()
    out = Path(options.out)
    checkpoints = out / "checkpoints"
    last = latest_checkpoint(checkpoints)
    if options.resume:
        if last is None:
            raise FileNotFoundError(f"--resume: no checkpoint (checkpoints/memret_<steps>_steps.zip) in {str(out)!r}")
        saved = load_run_config(out)
        started = json.loads((out / RUN_FILE).read_text()) if (out / RUN_FILE).is_file() else {}
        if started.get("controller", options.controller) != options.controller:
            raise ValueError(f"the run in {str(out)!r} was trained with controller {started['controller']!r}, not "
                             f"{options.controller!r}; a resumed run keeps its own")
        if config is not None and config.n_timesteps != saved.n_timesteps:
            saved.ppo["n_timesteps"] = config.n_timesteps  # the only thing a resume may change
            save_run_config(saved, out / CONFIG_FILE)
        config = saved
    else:
        if config is None:
            raise ValueError("a new run needs a config")
        retriever = start_retriever(config, options)
        if last is not None or (out / CONFIG_FILE).exists():
            raise FileExistsError(f"{str(out)!r} already holds a run; pass --resume to continue it or choose another --out")
        out.mkdir(parents=True, exist_ok=True)
        save_run_config(config, out / CONFIG_FILE)
        (out / RUN_FILE).write_text(json.dumps({"controller": options.controller, "seed": options.seed,
                                                "render_backend": options.render_backend}, indent=2) + "\n")

    options = replace(options, eval_episodes=options.eval_episodes or config.eval_episodes,
                      eval_every=options.eval_every or config.eval_every)
    initial = options.initial_eval_episodes or config.initial_eval_episodes or options.eval_episodes
    final = options.final_eval_episodes or config.final_eval_episodes or options.eval_episodes
    options = replace(options, initial_eval_episodes=min(initial, options.eval_episodes),  # never more than later ones
                      final_eval_episodes=max(final, options.eval_episodes))  # never fewer
    env_kwargs = env_kwargs_for(config, options.controller, options.render_backend)
    if controller is None and "tasks" not in config.env_kwargs:  # across tasks, each task makes its own by name
        controller = make_controller(options.controller, config.task_names[0])
    env_kwargs["controller"] = controller or options.controller
    done_steps = list_checkpoints(checkpoints)[-1][0] if options.resume else 0
    placement = {"backend": options.backend, "ray_address": options.ray_address}
    venv = make_decision_vec_env(config.n_envs, env_kwargs, seed=options.seed + done_steps, **placement)  # fresh on resume
    try:
        # the held-out envs share the controller's weights; a shallow copy keeps their episodes' state apart
        eval_env = make_decision_vec_env(config.n_envs, {**env_kwargs, "controller": copy.copy(env_kwargs["controller"])},
                                         **placement)
    except BaseException:
        venv.close()
        raise
    checkpointer = RoundCheckpointCallback(checkpoints, verbose=options.verbose)
    evaluator = RetrievalEvalCallback(eval_env, options.eval_episodes, options.eval_seed, options.eval_every,
                                      n_initial_episodes=options.initial_eval_episodes,
                                      n_final_episodes=options.final_eval_episodes, best_model_save_path=out,
                                      history_path=out / HISTORY_FILE,
                                      verbose=options.verbose)
    evaluator.listeners.extend(options.evaluation_listeners)
    timer = PhaseTimingCallback(evaluator)
    stopper = (StopOnRetrievalTarget(evaluator, options.stop_at_greedy, options.stop_patience, verbose=options.verbose)
               if options.stop_at_greedy is not None else None)
    start, stopped_by = time.perf_counter(), None
    try:
        if options.resume:
            model = MemRetPPO.load(last, env=venv)
        else:
            model = MemRetPPO(MemoryRetrievalPolicy, venv, seed=options.seed, verbose=options.verbose,
                              **config.algo_kwargs())
            if retriever is not None:
                model.policy.retriever.load_state_dict(retriever)
        model.set_logger(make_run_logger(out, options.log_formats))
        if not options.resume:
            model.save(out / INITIAL_MODEL)
        checkpointer.init_callback(model)  # so an interrupt even before the first round can save
        remaining = config.n_timesteps - model.num_timesteps
        learning = time.perf_counter()
        try:
            with stop_signals_interrupt():
                if remaining > 0:
                    callbacks = [RolloutRetrievalCallback(), evaluator, timer, checkpointer]
                    if stopper is not None:
                        callbacks.append(stopper)
                    if options.progress_bar:  # SB3's own bar stalls during evaluations and leaves them out of its time left
                        callbacks.append(RunProgressCallback(evaluator))
                    model.learn(remaining, callback=callbacks, reset_num_timesteps=not options.resume)
        except (KeyboardInterrupt, WorkerDiedError) as err:
            checkpointer.save()
            stopped_by = stop_reason(err)
        except BaseException:
            checkpointer.save()
            raise
        model_path = out / "final_model.zip"
        if stopped_by is None:
            model.save(model_path)
        seconds = {"setup": learning - began, **timer.split(), "learn": time.perf_counter() - learning}
        result = RunResult(out, model_path if stopped_by is None else latest_checkpoint(checkpoints),
                           model.num_timesteps, model._n_updates // model.n_epochs, time.perf_counter() - start,
                           stopped_by, evaluator.last_report, read_history(out), seconds,
                           target_reached=stopper.stopped if stopper else None)
        _write_summary(result, options)
        model.logger.close()
        if options.report is not None and stopped_by is None:
            result.report = options.report(result, eval_env)
        return result
    finally:
        with stop_signals_deferred():  # a second stop waits until every worker is closed
            try:
                venv.close()
            finally:
                eval_env.close()


def read_history(out: Path) -> list[dict[str, Any]]:
    """Every evaluation report of a run, oldest first; a round evaluated twice (resume) keeps its last."""
    path = Path(out) / HISTORY_FILE
    if not path.exists():
        return []
    rows = {}
    for line in path.read_text().splitlines():
        if line.strip():
            row = json.loads(line)
            rows[row["round"]] = row
    return [rows[r] for r in sorted(rows)]


def group_label(group: str) -> str:
    """A success group's column name: the drawer's groups are its layers."""
    return f"layer {group}" if group.isdigit() else group


def format_history(history: list[dict[str, Any]]) -> str:
    """The per-round evaluation table of a run, in markdown: success overall and per group (the drawer's
    layers, a cue's colours)."""
    groups = sorted({key for row in history for key in row["success"] if key != "overall"})
    lines = ["| round | decisions | greedy acc. | sampled | entropy | success | "
             + " | ".join(map(group_label, groups)) + " |", "|---|---|---|---|---|---|" + "---|" * len(groups)]
    for row in history:
        layers = " | ".join(f"{row['success'][group]:.0%}" if group in row["success"] else "-" for group in groups)
        lines.append(f"| {row['round']} | {row['timesteps']} | {row['greedy_accuracy']:.0%} | "
                     f"{row['sampled_fraction']:.0%} | {row['entropy']:.2f} | {row['success']['overall']:.0%} | {layers} |")
    return "\n".join(lines)


def retrieval_chance(out: Path) -> float | None:
    """K / capacity for a run's models: how often a uniformly random top-K holds the true memory."""
    for name in (INITIAL_MODEL, "final_model.zip"):
        if (Path(out) / name).exists():
            data, _, _ = load_from_zip_file(Path(out) / name, load_data=True)
            nvec = data["action_space"].nvec
            return len(nvec) / int(nvec[0])
    return None


def _write_summary(result: RunResult, options: RunOptions) -> None:
    summary = {"num_timesteps": result.num_timesteps, "rounds": result.rounds, "wall_seconds": result.wall_seconds,
               "seconds": result.seconds,
               "interrupted": result.interrupted, "stopped_by": result.stopped_by, "model": str(result.model_path), "controller": options.controller,
               "seed": options.seed, "retriever_from": str(options.retriever_from) if options.retriever_from else None,
               "eval_seed": options.eval_seed, "eval_episodes": options.eval_episodes,
               "initial_eval_episodes": options.initial_eval_episodes, "final_eval_episodes": options.final_eval_episodes,
               "stop_at_greedy": options.stop_at_greedy, "stop_patience": options.stop_patience,
               "stopped_at_target_round": result.target_reached,
               "final_eval": result.final.to_dict() if result.final else None}
    (result.out / "summary.json").write_text(json.dumps(summary, indent=2))


__all__ = ["HISTORY_FILE", "INITIAL_MODEL", "RUN_FILE", "RunOptions", "RunResult", "env_kwargs_for", "eval_env_kwargs", "format_history",
           "load_run_config", "read_history", "retrieval_chance", "start_retriever", "train"]
