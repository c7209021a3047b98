"""``report.md`` and ``success.png`` from a benchmark run's ``results.json``: the per-task table, the split's mean,
the per-memory-type breakdown, success per cue value (RememberColor9's per colour), and what was refused and why.
Generated from the results file alone, so every figure in it is one the run produced."""

from __future__ import annotations

import statistics
from collections import defaultdict
from pathlib import Path
from typing import Any, Mapping

from sb3_memret.benchmark.published import published_section

REPORT_FILE, FIGURE_FILE = "report.md", "success.png"
COMPARED_CONDITIONS = ("recall", "written", "oracle")  # our row beside the published figures: the first one run
MAX_CUES_SHOWN = 15  # the per-cue breakdown lists tasks whose cue takes at most this many values (the 5x3 tasks' 15)


def _cell(cell: Mapping[str, Any] | None) -> str:
    if cell is None:
        return ""
    if "refused" in cell:
        return "refused"
    if not cell.get("episodes"):
        return "error" if "error" in cell else "·"
    wins = sum(cell["successes"])
    partial = "" if cell.get("complete") else " *"
    return f"{100 * cell['success']:.0f}% ({wins}/{cell['episodes']}){partial}"


def _reads(tasks: Mapping[str, Any]) -> str:
    """What the controllers read, from the tasks that ran, and the weights they play (shipped, or a local path)."""
    reads = sorted({t["controller"]["reads"] for t in tasks.values() if "controller" in t})
    weights = sorted({t["controller"]["checkpoint"] for t in tasks.values() if "checkpoint" in t.get("controller", {})})
    where = f" (weights: {', '.join(weights)}; each file's SHA-256 in results.json)" if weights else ""
    return ("; ".join(reads) or "nothing (no task ran)") + where


def _complete(tasks: Mapping[str, Any], condition: str) -> dict[str, float]:
    """Each task's success under ``condition``, for the tasks that played all the protocol's episodes of it."""
    return {env_id: t["conditions"][condition]["success"] for env_id, t in tasks.items()
            if "conditions" in t and t["conditions"].get(condition, {}).get("complete")}


def _mean(values: list[float]) -> str:
    return f"{100 * sum(values) / len(values):.1f}%" if values else ""


def _by_cue(tasks: Mapping[str, Any], conditions: list[str]) -> list[str]:
    """The per-cue section: success per value of the episode's cue (``blue``), per task and condition, for the tasks
    whose cue takes at most ``MAX_CUES_SHOWN`` values (a continuous cue, a ball's speed, would list every seed)."""
    rows = []
    for env_id, t in tasks.items():
        cells = {c: cell["by_cue"] for c, cell in t.get("conditions", {}).items() if "by_cue" in cell}
        cues = sorted({cue for by_cue in cells.values() for cue in by_cue})
        if not cues or len(cues) > MAX_CUES_SHOWN:
            continue
        for cue in cues:
            counts = [cells.get(c, {}).get(cue) for c in conditions]
            rows.append(f"| {env_id} | {cue} | " + " | ".join(f"{n['successes']}/{n['episodes']}" if n else ""
                                                                for n in counts) + " |")
    if not rows:
        return []
    return ["", "## By cue", "",
            f"Successes per value of the episode's cue (its true facts), for tasks whose cue takes at most "
            f"{MAX_CUES_SHOWN} values over the run's seeds; the same seeds play every condition.", "",
            "| task | cue | " + " | ".join(conditions) + " |", "|---|---|" + "---|" * len(conditions), *rows]


def _cost(tasks: Mapping[str, Any], episodes: int) -> list[str]:
    """What each task cost to play: the median episode's seconds in its worker and control steps a second, and its
    cells' worker-minutes (each condition's median episode times the protocol's episodes). Medians, so that an episode
    a paused or swapping worker held up does not stand for the rest. Episodes logged before timing are left out."""
    rows = []
    for env_id, t in tasks.items():
        per_cell = [[(steps, sec) for steps, sec in zip(cell.get("episode_lengths", []), cell.get("seconds", []))
                     if sec is not None] for cell in t.get("conditions", {}).values()]
        timed = [pair for cell in per_cell for pair in cell]
        if not timed:
            continue
        minutes = sum(episodes * statistics.median(sec for _, sec in cell) / 60 for cell in per_cell if cell)
        rows.append(f"| {env_id} | {len(timed)} | {statistics.median(sec for _, sec in timed):.1f} | "
                    f"{statistics.median(steps / sec for steps, sec in timed):.0f} | {minutes:.1f} |")
    if not rows:
        return []
    return ["", "## Cost", "",
            "Wall time of each episode in its worker process (the workers share the CPU with whatever else ran), the "
            "median over the episodes timed; a task's cells: each condition's median episode times the episodes a "
            "cell plays.", "",
            "| task | episodes timed | seconds per episode | control steps per second | its cells, worker-minutes |",
            "|---|---|---|---|---|", *rows]


def privileged_upper_bound(content: Mapping[str, Any]) -> bool:
    """Whether a run's controller reads the simulator beyond the protocol's inputs (``results.json`` says so). A file
    written before it did is one: every controller then read more than the harness gives (the scripted experts'
    detector, the camera controllers' joint positions and velocities), and its writers the privileged view."""
    return bool(content.get("privileged_upper_bound", True))


def render_report(content: Mapping[str, Any]) -> str:
    """The markdown report of one run's results."""
    protocol, tasks = content["protocol"], content["tasks"]
    conditions = protocol["conditions"]
    seeds = protocol["seeds"]
    splits = sorted({t["split"] for t in tasks.values()})
    privileged = privileged_upper_bound(content)
    if privileged:
        inputs = ("- **A privileged upper bound, not a protocol entry**: the frozen controller reads the simulator "
                  f"beyond the protocol's policy inputs ({', '.join(protocol['policy_inputs'])}); the memory's own "
                  "inputs are the harness's. Its rows are kept out of the published-methods comparison.")
    else:
        inputs = f"- Policy inputs: {', '.join(protocol['policy_inputs'])} (never `oracle_info` or `task_cue`)."
    title = f"{protocol['controller']} controller" + (", a privileged upper bound" if privileged else "")
    lines = [
        f"# {protocol['benchmark']}: {', '.join(splits)} split, {title}",
        "",
        f"- Harness: `{protocol['harness']}`, wrappers `{protocol['wrapper_chain']}`, `{protocol['control_mode']}`, "
        f"`{protocol['obs_mode']}`, metric `{protocol['metric']}`.",
        inputs,
        f"- Episodes per task and condition: {protocol['episodes']}, {protocol['seed_set']} seeds "
        f"{seeds[0]}..{seeds[-1]}.",
        f"- Frozen controller: `{protocol['controller']}`, reading {_reads(tasks)}; it replans every "
        f"{protocol['replan_every'] or 'task-default (the table says)'} control steps.",
        "- Scenes: " + ("built anew at every reset, so no episode depends on those its worker played before."
                        if protocol.get("fresh_scenes", False) else
                        "reused across resets, as the harness's env does: an episode's physics can depend on those its "
                        "worker played before (a return's fourth decimal, rarely its outcome)."),
        "- Conditions: none (instruction only), oracle (the true fact in the prompt), wrong (a false fact worded "
        "alike), written (every fact the writer wrote from the cameras), recall (the facts a trained memory learner "
        "retrieves from a bank with decoys).",
        "",
        "## Per task",
        "",
        "| task | memory type | replan | " + " | ".join(conditions) + " |",
        "|---|---|---|" + "---|" * len(conditions),
    ]
    partial = False
    for env_id, t in tasks.items():
        if "refused" in t:
            cells = ["refused"] * len(conditions)
        else:
            cells = [_cell(t["conditions"].get(c)) for c in conditions]
        partial = partial or any(cell.endswith(" *") for cell in cells)
        lines.append(f"| {env_id} | {t['memory_type']} | {t.get('replan_every', '')} | " + " | ".join(cells) + " |")
    if partial:
        lines += ["", "`*`: not all of the protocol's episodes played yet."]
    lines += ["", "## Split mean", "",
              "| condition | tasks run | mean over tasks run | split mean, tasks not run counted as 0 |",
              "|---|---|---|---|"]
    for c in conditions:
        run = list(_complete(tasks, c).values())
        zero_filled = f"{100 * sum(run) / len(tasks):.1f}%" if tasks else ""
        lines.append(f"| {c} | {len(run)}/{len(tasks)} | {_mean(run)} | {zero_filled} |")
    lines += ["", "## By memory type", "", "| memory type | tasks | " + " | ".join(conditions) + " |",
              "|---|---|" + "---|" * len(conditions)]
    by_type: dict[str, list[str]] = defaultdict(list)
    for env_id, t in tasks.items():
        by_type[t["memory_type"]].append(env_id)
    for memory_type, ids in sorted(by_type.items()):
        cells = []
        for c in conditions:
            done = _complete({i: tasks[i] for i in ids}, c)
            cells.append(f"{_mean(list(done.values()))} ({len(done)})" if done else "")
        lines.append(f"| {memory_type} | {len(ids)} | " + " | ".join(cells) + " |")
    lines += _by_cue(tasks, conditions)
    # what a memory method is compared on: a condition whose facts come from the cameras, else the oracle's (marked
    # by its name); none and wrong are no memory method's, so a run of only those shows the published rows alone
    best = next((c for c in COMPARED_CONDITIONS if c in conditions), None)
    if not privileged:  # an upper bound is no method's entry: it is not set beside the published ones
        lines += published_section({env_id: _cell(t["conditions"].get(best)) if best else ""
                                    for env_id, t in tasks.items() if "conditions" in t}, protocol["controller"],
                                   best)
    lines += _cost(tasks, protocol["episodes"])
    refused = [(env_id, t["refused"]) for env_id, t in tasks.items() if "refused" in t]
    refused += [(f"{env_id} ({c})", cell.get("refused") or cell.get("error"))
                for env_id, t in tasks.items() for c, cell in t.get("conditions", {}).items()
                if "refused" in cell or ("error" in cell and not cell.get("episodes"))]
    if refused:
        lines += ["", "## Refused here", "", "| task | why |", "|---|---|"]
        lines += [f"| {name} | {why} |" for name, why in refused]
    lines += ["", f"![success per task and condition]({FIGURE_FILE})", ""]
    return "\n".join(lines)


def plot_success(content: Mapping[str, Any], path: Path) -> None:
    """A bar per (task, condition) of the tasks that played: success over the protocol's episodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conditions = content["protocol"]["conditions"]
    rows = [(env_id.removesuffix("-VLA-v0"), t) for env_id, t in content["tasks"].items() if "conditions" in t]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.6 * len(rows) * max(1, len(conditions)) / 2), 4.0))
    width = 0.8 / max(1, len(conditions))
    for k, condition in enumerate(conditions):
        xs, ys = [], []
        for i, (_, t) in enumerate(rows):
            cell = t["conditions"].get(condition) or {}
            if cell.get("success") is not None:
                xs.append(i + (k - (len(conditions) - 1) / 2) * width)
                ys.append(100 * cell["success"])
        ax.bar(xs, ys, width, label=condition)
    ax.set_xticks(range(len(rows)), [name for name, _ in rows], rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("success once (%)")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=8, ncols=len(conditions))
    ax.set_title(f"{content['protocol']['benchmark']}, {content['protocol']['seed_set']} seeds")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_report(content: Mapping[str, Any], out: Path) -> Path:
    """Write ``report.md`` and its figure into ``out``; the report's path."""
    out = Path(out)
    plot_success(content, out / FIGURE_FILE)
    (out / REPORT_FILE).write_text(render_report(content))
    return out / REPORT_FILE


__all__ = ["FIGURE_FILE", "MAX_CUES_SHOWN", "REPORT_FILE", "plot_success", "render_report", "write_report"]
