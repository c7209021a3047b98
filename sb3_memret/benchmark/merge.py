"""One table from several run folders played apart (on two machines, or a condition played into a folder of its
own): the episodes of each source that the destination lacks are appended to its log, and its results are written
again over the union of their tasks, conditions and learners. Only folders of one protocol merge, only episodes
that today's code, controller and learner would play count (``Plan.current``), and an episode the destination
already holds is never added twice."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from sb3_memret.benchmark.agent import CONDITIONS
from sb3_memret.benchmark.learners import stored_learners
from sb3_memret.benchmark.runner import (PROTOCOL_FILE, RESULTS_FILE, Protocol, RunFolder, Unit, done_units, plan,
                                         write_results)


@dataclass
class Merged:
    """What a merge did: the destination's new results, the episodes added per (task, condition), and per source
    the episodes left out because other code, another controller or another learner played them."""

    content: dict[str, Any]
    added: dict[tuple[str, str], int] = field(default_factory=dict)
    left_out: dict[str, int] = field(default_factory=dict)


def _saved(folder: Path) -> tuple[Protocol, dict[str, Any]]:
    """A run folder's protocol and results; a ValueError naming the folder and the file it lacks."""
    for name in (PROTOCOL_FILE, RESULTS_FILE):
        if not (folder / name).is_file():
            raise ValueError(f"{folder} is not a benchmark run folder: it has no {name}")
    return RunFolder(folder).protocol(), json.loads((folder / RESULTS_FILE).read_text())


def merge_runs(sources: Iterable[Path], into: Path, only: Iterable[str] | None = None) -> Merged:
    """Append to ``into``'s episode log the current episodes of each of ``sources`` that it lacks (of the tasks in
    ``only``, if given), and write its results again over the union of their tasks, conditions and learners
    (``into``'s learners first). Holds ``into`` as a benchmark does, so nothing plays into it meanwhile."""
    into = Path(into)
    only = None if only is None else set(only)
    protocol, saved = _saved(into)
    tasks = list(saved["tasks"])
    conditions = set(saved["protocol"]["conditions"])
    learners = list(stored_learners(saved["protocol"].get("learners")))
    read = []
    for source in map(Path, sources):
        if source.resolve() == into.resolve():
            raise ValueError(f"{source} is the folder merged into")
        theirs, content = _saved(source)
        diff = protocol.differing(theirs)
        if diff:
            mine, other = protocol.to_json(), theirs.to_json()
            raise ValueError(f"{source} was played under another protocol than {into} ("
                             + ", ".join(f"{k}: {other.get(k)!r} against {mine.get(k)!r}" for k in diff) + ")")
        tasks += [env_id for env_id in content["tasks"] if env_id not in tasks and (only is None or env_id in only)]
        conditions |= set(content["protocol"]["conditions"])
        learners += [p for p in stored_learners(content["protocol"].get("learners")) if p not in learners]
        read.append((source, RunFolder(source).episodes()))
    run = plan(protocol, [c for c in CONDITIONS if c in conditions], env_ids=tasks, learners=learners)
    folder = RunFolder(into)
    merged = Merged(content={})
    with folder.playing():
        records = folder.episodes()
        have: set[Unit] = done_units(run, records)
        for source, episodes in read:
            for record in episodes:
                unit = Unit(record["env_id"], record["condition"], int(record["seed"]))
                if "error" in record or unit in have or (only is not None and unit.env_id not in only):
                    continue
                if record["env_id"] not in run.controllers or not run.current(record):
                    merged.left_out[str(source)] = merged.left_out.get(str(source), 0) + 1
                    continue
                folder.log(dict(record))
                records.append(record)
                have.add(unit)
                merged.added[unit.env_id, unit.condition] = merged.added.get((unit.env_id, unit.condition), 0) + 1
        merged.content = write_results(into, run, records)
    return merged


__all__ = ["Merged", "merge_runs"]
