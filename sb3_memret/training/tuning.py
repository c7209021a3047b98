"""Hyperparameter search over a zoo config with Optuna, the way rl-zoo does it: a TPE sampler, a median
pruner on the held-out evaluations, every trial a full run folder, and the best trial written back as a
zoo config.

The objective is the mean held-out greedy retrieval accuracy over a trial's evaluations (the area under
its learning curve): it rewards retrieval learned early and kept, and it is what a trial reports at each
evaluation, so the pruner compares trials round for round. The study lives in ``OUT/study.db``, so an
interrupted search continues where it stopped when the same command runs again.
"""

from __future__ import annotations

import copy
import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import yaml

from sb3_memret.evaluation.retrieval import RetrievalReport
from sb3_memret.training.config import TrainConfig, parse_section
from sb3_memret.controllers import FrozenController
from sb3_memret.common.seeds import HELD_OUT_SEED
from sb3_memret.training.run import RunOptions, train

STUDY_FILE = "study.db"
BEST_CONFIG = "best_config.yml"
TRIALS_FILE = "trials.csv"


def sample_hyperparameters(trial: Any, n_envs: int) -> dict[str, Any]:
    """One point of the search space: PPO's round size, step and clipping, GAE's lambda, the entropy bonus,
    and the retrieval policy's temperature, exploration and retriever (``n_envs`` bounds the batch size). Rounds
    go up to 256 decisions per env: on the objects task rounds of ~3 episodes settled on a safe memory where
    rounds of ~12 learned (issue 24's notes)."""
    n_steps = trial.suggest_categorical("n_steps", [16, 32, 64, 128, 256])
    batch_size = trial.suggest_categorical("batch_size", [16, 32, 64, 128])
    return {
        "n_steps": n_steps,
        "batch_size": min(batch_size, n_steps * n_envs),
        "n_epochs": trial.suggest_categorical("n_epochs", [2, 4, 8]),
        "learning_rate": trial.suggest_float("learning_rate", 1e-4, 3e-3, log=True),
        "gae_lambda": trial.suggest_categorical("gae_lambda", [0.5, 0.7, 0.8, 0.9, 0.95]),
        "clip_range": trial.suggest_categorical("clip_range", [0.1, 0.2, 0.3]),
        "ent_coef": trial.suggest_float("ent_coef", 1e-4, 1e-2, log=True),
        "policy_kwargs": {
            "temperature": trial.suggest_categorical("temperature", [0.25, 0.5, 1.0]),
            "exploration": trial.suggest_categorical("exploration", ["decision", "episode"]),
            "retriever": trial.suggest_categorical("retriever", ["mlp", "set"]),
        },
    }


def apply_hyperparameters(config: TrainConfig, params: dict[str, Any]) -> TrainConfig:
    """``config`` with ``params`` (PPO keys and a ``policy_kwargs`` mapping) put in, validated as a zoo section."""
    section = {**copy.deepcopy(config.ppo), "policy_kwargs": dict(config.policy_kwargs),
               "env_kwargs": copy.deepcopy(config.env_kwargs)}
    for key, value in params.items():
        if key == "policy_kwargs":
            section["policy_kwargs"].update(value)
        else:
            section[key] = value
    return parse_section(section, config.env_id, where="tuned config")


@dataclass
class TuneOptions:
    """How to search: trials, where the trial runs go, and how each is evaluated."""

    out: Path
    trials: int = 20
    controller: str = "scripted"
    seed: int = 0  # every trial trains with this seed; the sampler draws from it too
    eval_episodes: int = 20
    eval_every: int = 2
    eval_seed: int = HELD_OUT_SEED
    startup_trials: int = 5  # trials before the sampler models the space and the pruner may prune
    warmup_evaluations: int = 2  # evaluations a trial always gets before it may be pruned
    render_backend: str = "none"


class TrialReporter:
    """Reports each held-out evaluation of a trial's run to Optuna and stops the run when it is pruned."""

    def __init__(self, trial: Any):
        self.trial, self.accuracies = trial, []

    def evaluation_started(self, round_: int, episodes: int) -> None:
        self.round = round_

    def evaluation_episode(self) -> None:
        pass

    def evaluation_finished(self, report: RetrievalReport | None) -> None:
        import optuna

        if report is None:
            return
        self.accuracies.append(report.greedy_accuracy)
        self.trial.report(self.objective, step=self.round)
        if self.trial.should_prune():
            raise optuna.TrialPruned(f"pruned at round {self.round}: mean greedy accuracy {self.objective:.3f}")

    @property
    def objective(self) -> float:
        return sum(self.accuracies) / len(self.accuracies)


def tune(config: TrainConfig, options: TuneOptions, controller: FrozenController | None = None,
         on_trial: Callable[[Any], None] | None = None):
    """Run ``options.trials`` more trials of the study in ``options.out`` (created, or continued) and write
    the best trial's config (``best_config.yml``) and every trial (``trials.csv``); returns the study."""
    import optuna

    out = Path(options.out)
    out.mkdir(parents=True, exist_ok=True)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(
        study_name="memret", storage=f"sqlite:///{out / STUDY_FILE}", load_if_exists=True, direction="maximize",
        sampler=optuna.samplers.TPESampler(seed=options.seed, n_startup_trials=options.startup_trials),
        pruner=optuna.pruners.MedianPruner(n_startup_trials=options.startup_trials,
                                           n_warmup_steps=options.warmup_evaluations * options.eval_every))

    def objective(trial: Any) -> float:
        params = sample_hyperparameters(trial, config.n_envs)
        trial_config = apply_hyperparameters(config, params)
        reporter = TrialReporter(trial)
        result = train(trial_config, RunOptions(
            out=out / f"trial-{trial.number}", controller=options.controller, seed=options.seed,
            eval_episodes=options.eval_episodes, eval_every=options.eval_every, eval_seed=options.eval_seed,
            log_formats=("csv",), render_backend=options.render_backend, evaluation_listeners=(reporter,)),
            controller)
        if result.interrupted:
            raise KeyboardInterrupt(result.stopped_by)
        return reporter.objective

    callbacks = [lambda study, trial: on_trial(trial)] if on_trial else None
    try:
        study.optimize(objective, n_trials=options.trials, callbacks=callbacks)
    finally:
        write_results(study, config, out)
    return study


def write_results(study: Any, config: TrainConfig, out: Path) -> Path | None:
    """``trials.csv`` (every trial: number, state, objective, parameters) and, once a trial has completed,
    ``best_config.yml``: the zoo config with the best trial's hyperparameters, keyed by the same env id."""
    import optuna

    names = sorted({name for trial in study.trials for name in trial.params})
    with (out / TRIALS_FILE).open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["number", "state", "objective", "last_round", *names])
        for trial in study.trials:
            last = max(trial.intermediate_values, default="")
            writer.writerow([trial.number, trial.state.name, "" if trial.value is None else f"{trial.value:.4f}", last,
                             *(trial.params.get(name, "") for name in names)])
    complete = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    if not complete:
        return None
    best = max(complete, key=lambda t: t.value)
    tuned = apply_hyperparameters(config, sample_hyperparameters(optuna.trial.FixedTrial(best.params), config.n_envs))
    section = {**tuned.ppo, "policy_kwargs": tuned.policy_kwargs, "env_kwargs": tuned.env_kwargs}
    header = (f"# Found by `sb3-memret tune`: trial {best.number} of {len(study.trials)}, mean held-out greedy accuracy "
              f"{best.value:.3f} over its evaluations (run folder {out / f'trial-{best.number}'}).\n")
    path = out / BEST_CONFIG
    path.write_text(header + yaml.safe_dump({config.env_id: section}, sort_keys=False))
    return path


__all__ = ["BEST_CONFIG", "STUDY_FILE", "TRIALS_FILE", "TrialReporter", "TuneOptions", "apply_hyperparameters",
           "sample_hyperparameters", "tune", "write_results"]
