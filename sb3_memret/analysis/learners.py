"""A learners folder side by side: one row a task's memory learner (``sb3-memret benchmark learners``), how long it
trained, how its run ended, when held-out retrieval was learned and where it ended (the table the command prints at
its end and the docs' results pages draw from a committed learners folder)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterable, Sequence

from sb3_memret.analysis.sweep import MASTERY, is_run, run_row

LEARNERS_FILE = "learners.json"  # the tasks a learners folder was asked to train, in the order asked


def is_learners_folder(folder: Path) -> bool:
    """Whether ``folder`` is a learners folder (``benchmark learners --out``), not a seed sweep."""
    return (Path(folder) / LEARNERS_FILE).is_file()


def record_tasks(folder: Path, env_ids: Iterable[str]) -> list[str]:
    """Add ``env_ids`` to the tasks ``folder``'s index lists (created if missing; earlier ones kept, in order); the
    tasks listed now."""
    path = Path(folder) / LEARNERS_FILE
    tasks = json.loads(path.read_text())["tasks"] if path.is_file() else []
    tasks += [env_id for env_id in env_ids if env_id not in tasks]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"tasks": tasks}, indent=2) + "\n")
    return tasks


def learner_rows(folder: Path) -> list[dict[str, Any]]:
    """One row a task the folder's index lists: a finished run's figures (``run_row``), with its task, decisions,
    how it ended and its ``summary.json``; a task without a finished run is ``training`` (a run folder there) or
    ``not started``."""
    folder = Path(folder)
    if not is_learners_folder(folder):
        raise FileNotFoundError(f"{folder} has no {LEARNERS_FILE}: not a learners folder (benchmark learners --out)")
    rows = []
    for env_id in json.loads((folder / LEARNERS_FILE).read_text())["tasks"]:
        run = folder / env_id
        if not is_run(run):
            rows.append({"task": env_id, "state": "training" if run.is_dir() else "not started"})
            continue
        summary = json.loads((run / "summary.json").read_text())
        stopped = summary.get("stopped_at_target_round")
        ended = ("interrupted" if summary.get("interrupted") else
                 f"stopped at round {stopped}: greedy at the target" if stopped is not None else "its budget")
        rows.append({**run_row(run), "task": env_id, "state": "trained", "ended": ended,
                     "decisions": summary.get("num_timesteps", float("nan")), "summary": summary})
    return rows


def learners_table(rows: Sequence[dict[str, Any]]) -> list[str]:
    """The markdown table of ``rows`` (``learner_rows``'), one line a task, then how many are trained and reached
    greedy retrieval of MASTERY."""
    lines = [f"| task | rounds (decisions) | ended | first round with greedy ≥ {MASTERY:.0%} | held-out episodes | "
             "greedy | sampled | success | training minutes |", "|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        if row["state"] != "trained":
            lines.append(f"| {row['task']} | {row['state']} | | | | | | | |")
            continue
        first = "never" if row["first_mastered"] != row["first_mastered"] else str(row["first_mastered"])
        lines.append(f"| {row['task']} | {row['round']} ({row['decisions']}) | {row['ended']} | {first} | "
                     f"{row['episodes']} | {row['greedy']:.0%} | {row['sampled']:.0%} | {row['success']:.0%} | "
                     f"{row['minutes']:.1f} |")
    trained = [row for row in rows if row["state"] == "trained"]
    mastered = sum(row["greedy"] >= MASTERY for row in trained)
    lines += ["", f"{len(trained)} of {len(rows)} trained; {mastered} of them end at greedy retrieval ≥ {MASTERY:.0%} "
                  f"on their held-out episodes; {sum(row['minutes'] for row in trained):.0f} minutes of training."]
    return lines


__all__ = ["LEARNERS_FILE", "is_learners_folder", "learner_rows", "learners_table", "record_tasks"]
