"""The memory learners the ``recall`` condition needs, and where each task finds its own.

Trained by one ``train recall`` run per task of a split, into ``DIR/<env id>/``, each on its task's zoo config, one
after another; a finished run is kept, an interrupted one resumes from its last checkpoint, and one stopped before its
first checkpoint starts again. Found in ``--learners``' folders and model files, in the order given
(``find_learner``)."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

from sb3_memret.benchmark.agent import learned_as, short_variant

LEARNER_FILE = "final_model.zip"  # a trained learner's model in its run folder

# The memory learner across the short split shipped in the package (``make learner-multitask``: ``train recall --tasks
# mikasa:short``, the zoo's ``multitask`` section, scripted experts), which the recall condition plays when no
# --learners is given: its model, beside its run's config.yml (the bank settings of each task) and summary.json.
SHIPPED_LEARNER = Path(__file__).resolve().parent / "checkpoints" / "mikasa-short-learner" / LEARNER_FILE
SHIPPED_LEARNER_COMMAND = "make learner-multitask"


def shipped_learner() -> Path:
    """The shipped learner across the short split's tasks; a FileNotFoundError naming how to rebuild it if missing."""
    from sb3_memret.training.run import CONFIG_FILE

    for name in (LEARNER_FILE, CONFIG_FILE):
        if not (SHIPPED_LEARNER.parent / name).is_file():
            raise FileNotFoundError(f"the shipped memory learner is missing {name} in {SHIPPED_LEARNER.parent}; "
                                    f"rebuild it with `{SHIPPED_LEARNER_COMMAND}`, or pass --learners")
    return SHIPPED_LEARNER


@dataclass(frozen=True)
class LearnerOutcome:
    """What became of one task's learner: trained now, there already, or refused with the reason."""

    env_id: str
    status: str  # "trained", "kept", "refused"
    detail: str = ""


def train_learners(env_ids: list[str], out: Path, controller: str = "scripted", seed: int = 0,
                   eval_episodes: int = 50, load_config: Callable[[str], object] | None = None,
                   on_outcome: Callable[[LearnerOutcome], None] | None = None, stop_at_greedy: float | None = None,
                   stop_patience: int = 2) -> list[LearnerOutcome]:
    """Train (or resume, or keep) the memory learner of each task in ``env_ids`` into ``out/<env id>``, listing the
    tasks in ``out``'s index (``analysis.learners``).
    Held-out evaluations during training play the task's development seeds, never the benchmark's; with
    ``stop_at_greedy`` a run ends once ``stop_patience`` of them in a row retrieve that well."""
    from sb3_memret.training.config import load_task_config
    from sb3_memret.controller_specs import make_controller
    from sb3_memret.tasks import check_task_name, make_task
    from sb3_memret.analysis.learners import record_tasks
    from sb3_memret.callbacks import latest_checkpoint
    from sb3_memret.training.run import RunOptions, train

    load_config = load_config or load_task_config
    record_tasks(out, env_ids)  # the folder's index: the docs' learners page and `benchmark learners`' table read it
    outcomes = []
    for env_id in env_ids:
        folder = Path(out) / env_id
        if (folder / LEARNER_FILE).is_file():
            outcome = LearnerOutcome(env_id, "kept", str(folder / LEARNER_FILE))
        else:
            try:
                check_task_name(env_id)
                task = make_task(env_id)
                config = load_config(env_id)
                built = make_controller(controller, task)
            except (ValueError, FileNotFoundError, ImportError) as err:
                outcome = LearnerOutcome(env_id, "refused", str(err).splitlines()[0])
            else:
                resume = latest_checkpoint(folder / "checkpoints") is not None
                if not resume and folder.exists():  # a run stopped before its first checkpoint: nothing learned
                    shutil.rmtree(folder)
                options = RunOptions(out=folder, controller=controller, seed=seed, resume=resume,
                                     eval_episodes=eval_episodes, render_backend=task.default_render_backend,
                                     log_formats=("csv",), stop_at_greedy=stop_at_greedy,
                                     stop_patience=stop_patience)
                result = train(None if resume else config, options, built)
                if result.interrupted:
                    raise KeyboardInterrupt(result.stopped_by)
                reached = ("" if result.target_reached is None
                           else f", stopped early: held-out greedy retrieval at the target at round {result.target_reached}")
                outcome = LearnerOutcome(env_id, "trained", f"{result.rounds} rounds in "
                                                            f"{result.wall_seconds / 60:.1f} min{reached}")
        outcomes.append(outcome)
        if on_outcome is not None:
            on_outcome(outcome)
    return outcomes


def learner_sources(learners: Path | Iterable[Path] | None) -> tuple[Path, ...]:
    """``--learners`` as a tuple of paths, in the order given (one path, several, or none); ``shipped`` names the
    package's learner across the short split, wherever the package is installed."""
    if learners is None:
        return ()
    if isinstance(learners, (str, Path)):
        learners = [learners]
    return tuple(SHIPPED_LEARNER if str(source) == "shipped" else Path(source) for source in learners)


def find_learner(learners: Path | Iterable[Path] | None, env_id: str) -> tuple[Path | None, str]:
    """The memory learner that serves ``env_id``, the first of ``learners`` that does, or None and why none does.

    A folder serves a task with ``DIR/<env id>/final_model.zip``, or a -Long variant without one of its own with its
    short task's (``DIR/RememberColor3-VLA-v0/``): the bank holds the same facts, only the delay before they are
    needed grows, which is what its row measures. A model file serves every task it was trained on: a learner across
    tasks (``train recall --tasks``) its tasks and their -Long variants (``agent.learned_as``), a one-task learner
    the task it is asked for (``MemoryLearner`` checks it when it loads)."""
    sources = learner_sources(learners)
    if not sources:
        return None, "no learners folder given (--learners DIR, with DIR/<env id>/final_model.zip)"
    why = []
    for source in sources:
        if source.is_file():
            trained_on = learner_tasks(source)
            if trained_on is None or learned_as(env_id, trained_on) is not None:
                return source, ""
            why.append(f"the learner across tasks {source} was not trained on it")
            continue
        own, short = source / env_id / LEARNER_FILE, short_variant(env_id)
        for candidate in (own, None if short is None else source / short / LEARNER_FILE):
            if candidate is not None and candidate.is_file():
                return candidate, ""
        why.append(f"no trained memory learner: expected {own}")
    return None, "; ".join(why)


def learner_path(learners: Path | Iterable[Path] | None, env_id: str) -> Path | None:
    """The model file of the memory learner that serves ``env_id`` (``find_learner``), or None."""
    return find_learner(learners, env_id)[0]


def stored_learners(value: str | list[str] | None) -> tuple[Path, ...]:
    """The learners a run folder's ``results.json`` records: one path (a string), several (a list) or none."""
    return learner_sources(None if value is None else [value] if isinstance(value, str) else value)


def learners_json(learners: tuple[Path, ...]) -> str | list[str] | None:
    """The learners as ``results.json`` records them: one path as a string, several as a list, none as null; the
    package's own as ``shipped``, so that a table read on another checkout finds it."""
    named = [("shipped" if Path(p).resolve() == SHIPPED_LEARNER.resolve() else str(p)) for p in learners]
    return None if not named else named[0] if len(named) == 1 else named


def learner_tasks(path: Path) -> list[str] | None:
    """The tasks of a learner across tasks (its run folder's config), or None for a one-task learner."""
    from sb3_memret.training.run import CONFIG_FILE, load_run_config

    for folder in (path.parent, path.parent.parent):
        if (folder / CONFIG_FILE).is_file():
            tasks = load_run_config(folder).env_kwargs.get("tasks")
            return list(tasks) if tasks is not None else None
    return None


__all__ = ["LEARNER_FILE", "SHIPPED_LEARNER", "LearnerOutcome", "find_learner", "learner_path", "learner_sources",
           "learner_tasks", "learners_json", "shipped_learner", "stored_learners", "train_learners"]
