"""The memory learners the ``recall`` condition needs: one ``train recall`` run per task of a split, into
``DIR/<env id>/``, each on its task's zoo config, one after another; a finished run is kept, an interrupted one
resumes from its last checkpoint, and one stopped before its first checkpoint starts again."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from sb3_memret.benchmark.runner import LEARNER_FILE

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
    """Train (or resume, or keep) the memory learner of each task in ``env_ids`` into ``out/<env id>``.
    Held-out evaluations during training play the task's development seeds, never the benchmark's; with
    ``stop_at_greedy`` a run ends once ``stop_patience`` of them in a row retrieve that well."""
    from sb3_memret.training.config import load_task_config
    from sb3_memret.controller_specs import make_controller
    from sb3_memret.tasks import check_task_name, make_task
    from sb3_memret.callbacks import latest_checkpoint
    from sb3_memret.training.run import RunOptions, train

    load_config = load_config or load_task_config
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


__all__ = ["LearnerOutcome", "train_learners"]
