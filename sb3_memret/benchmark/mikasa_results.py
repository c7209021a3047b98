"""A run's table in MIKASA-Robo-VLA's own result layout: per condition, one ``<env id>.json`` per task as its
``evaluate_task`` returns it and a ``summary.json`` from its ``summarize_task_results``, written by its
``write_benchmark_results``, so that the entry reads with the benchmark's own tools. Built from ``results.json``
alone, for the task cells that played all of the protocol's episodes."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping

MIKASA_DIR = "mikasa"  # under a run folder: mikasa/<condition>/<env id>.json and summary.json
ACTION_CHUNK_SIZE = 1  # the agent's ``chunk_size``: the harness calls it at every control step


def task_result(env_id: str, task: Mapping[str, Any], condition: str, protocol: Mapping[str, Any],
                privileged: bool, logged: Mapping[tuple[str, str, int], Mapping[str, Any]] | None = None
                ) -> dict[str, Any]:
    """``evaluate_task``'s dict for one task's complete cell of ``condition``; a cell written before results held
    returns and lengths takes them from the run's episode log (``logged``: its last record per episode)."""
    cell = dict(task["conditions"][condition])
    successes = [bool(s) for s in cell["successes"]]
    if "returns" not in cell:
        records = [(logged or {}).get((env_id, condition, int(seed)), {}) for seed in cell["seeds"]]
        cell["returns"] = [r.get("return") for r in records]
        cell["episode_lengths"] = [r.get("steps") for r in records]
    missing = [seed for seed, r in zip(cell["seeds"], cell["returns"]) if r is None]
    if missing:
        raise ValueError(f"{env_id} ({condition}): no return logged for seeds {missing[:3]}: MIKASA's layout needs one "
                         "per episode")
    returns = [float(r) for r in cell["returns"]]
    controller = task.get("controller", {})
    return {
        "env_id": env_id,
        "split": str(task["split"]).title(),
        "memory_type": task["memory_type"],
        "start_seed": int(cell["seeds"][0]),
        "n_episodes": len(successes),
        "successes": successes,
        "returns": returns,
        "sr": sum(successes) / len(successes),
        "mean_return": sum(returns) / len(returns),
        "benchmark_commit": None,
        "control_mode": protocol["control_mode"],
        "obs_mode": protocol["obs_mode"],
        "wrapper_chain": protocol["wrapper_chain"],
        "action_chunk_size": ACTION_CHUNK_SIZE,
        "model": {"name": "sb3-memret", "condition": condition, "controller": controller.get("name"),
                  "controller_sha256": controller.get("sha256"), "reads": controller.get("reads"),
                  "privileged_upper_bound": privileged, "seed_set": protocol.get("seed_set")},
        "episode_lengths": list(cell.get("episode_lengths") or []),
        "episode_seeds": [int(s) for s in cell["seeds"]],
    }


def mikasa_task_results(content: Mapping[str, Any], logged: Mapping[tuple[str, str, int], Mapping[str, Any]] | None
                        = None) -> dict[str, list[dict[str, Any]]]:
    """Per condition, ``evaluate_task``'s dict of every task whose cell of it is complete."""
    from sb3_memret.benchmark.report import privileged_upper_bound

    protocol, privileged = content["protocol"], privileged_upper_bound(content)
    by_condition: dict[str, list[dict[str, Any]]] = {}
    for condition in protocol["conditions"]:
        done = [task_result(env_id, task, condition, protocol, privileged, logged)
                for env_id, task in content["tasks"].items()
                if task.get("conditions", {}).get(condition, {}).get("complete")]
        if done:
            by_condition[condition] = done
    return by_condition


def write_mikasa_results(out: Path, content: Mapping[str, Any], records: Iterable[Mapping[str, Any]] = ()
                         ) -> list[Path]:
    """Write ``out/mikasa/<condition>/`` with MIKASA's own ``write_benchmark_results`` and ``summarize_task_results``
    (``records``: the run's episode log, for cells written before results held returns); the condition folders
    written."""
    from mikasa_robo_suite.vla.benchmarking import summarize_task_results, write_benchmark_results

    logged = {(r["env_id"], r["condition"], int(r["seed"])): r for r in records if "error" not in r}
    written = []
    for condition, task_results in mikasa_task_results(content, logged).items():
        folder = Path(out) / MIKASA_DIR / condition
        write_benchmark_results(folder, task_results, summarize_task_results(task_results))
        written.append(folder)
    return written


__all__ = ["MIKASA_DIR", "mikasa_task_results", "task_result", "write_mikasa_results"]
