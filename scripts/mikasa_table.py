"""The MIKASA table: each trained memory learner's task with no fact, a wrong fact, the oracle fact and the
learned memory, beside the published end-to-end VLAs; at the tasks' development seeds, and at MIKASA's evaluation
seeds (its test set) only with ``--seeds protocol``, for the final figure.

For each run folder (``sb3-memret train recall --task T``) it plays, through the CLI a user would type,
``rollout --task T --controller C --condition none|wrong|oracle --episodes N --replan-every R --seeds S --json``
with the run's controller and replan interval, and ``eval RUN/final_model.zip --episodes N --seeds S --json``
(recall, greedy retrieval), then prints one markdown row per task and, below, the published RememberColor figures.
``--out DIR`` also writes ``mikasa_table.md`` and ``mikasa_table.json``.

Usage: ``python scripts/mikasa_table.py runs/recall-RememberColor3-VLA-v0-seed0 ... [--episodes 50]
[--seeds protocol] [--model best_model.zip] [--out runs/mikasa-table]``.

The published figures are success rates in % over 100 episodes on the -v0 tasks, end-to-end VLAs trained
offline on MIKASA's demonstrations: Octo-small, OpenVLA (action chunk 8) and pi0 from the MIKASA-Robo paper
(Cherepanov et al., 2025), MemoryVLA from its paper (Shi et al., 2025), ELMUR from its paper (Cherepanov
et al., 2025), as gathered by MIKASA-Robo's public leaderboard.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

# success (%) on RememberColor3 / 5 / 9-VLA-v0, as published (see the module docstring)
PUBLISHED: dict[str, dict[str, int]] = {
    "Octo-small": {"RememberColor3-VLA-v0": 45, "RememberColor5-VLA-v0": 17, "RememberColor9-VLA-v0": 11},
    "OpenVLA (chunk 8)": {"RememberColor3-VLA-v0": 59, "RememberColor5-VLA-v0": 16, "RememberColor9-VLA-v0": 6},
    "pi0": {"RememberColor3-VLA-v0": 35, "RememberColor5-VLA-v0": 22, "RememberColor9-VLA-v0": 15},
    "MemoryVLA": {"RememberColor3-VLA-v0": 44, "RememberColor5-VLA-v0": 30, "RememberColor9-VLA-v0": 20},
    "ELMUR": {"RememberColor3-VLA-v0": 89, "RememberColor5-VLA-v0": 19, "RememberColor9-VLA-v0": 23},
}
CONDITIONS = ("none", "wrong", "oracle")


def cli_json(args: list[str]) -> dict[str, Any]:
    """Run ``sb3-memret ARGS --json`` (the installed CLI, beside this Python) and parse its last stdout line."""
    command = [str(Path(sys.executable).with_name("sb3-memret")), *args, "--json"]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"`{' '.join(command)}` failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def run_setting(run: Path) -> tuple[str, str, int]:
    """The task, controller and replan interval a recall run was trained with (its config.yml and
    summary.json), which the rollouts beside its evaluation use too."""
    from sb3_memret.training.run import CONFIG_FILE, load_run_config

    summary_path = run / "summary.json"
    if not summary_path.is_file() or not (run / CONFIG_FILE).is_file():
        raise SystemExit(f"{run}: no summary.json or {CONFIG_FILE}, so not a finished `sb3-memret train recall` run")
    controller = json.loads(summary_path.read_text()).get("controller")
    env_kwargs = load_run_config(run).env_kwargs
    task = env_kwargs.get("task")
    if not controller or not task:
        raise SystemExit(f"{run} names no task or controller; is it a MIKASA task's recall run?")
    return task, controller, int(env_kwargs.get("replan_every", 4))


def task_row(run: Path, episodes: int, model: str, seeds: str = "dev") -> dict[str, Any]:
    """One task's figures at its ``seeds`` (the CLI's ``--seeds``): success per prompt condition and with the
    learned memory, and greedy retrieval."""
    task, controller, replan_every = run_setting(run)
    row: dict[str, Any] = {"task": task, "controller": controller, "run": str(run), "episodes": episodes,
                           "seeds": seeds, "replan_every": replan_every}
    for condition in CONDITIONS:
        result = cli_json(["rollout", "--task", task, "--controller", controller, "--condition", condition,
                           "--episodes", str(episodes), "--replan-every", str(replan_every), "--seeds", seeds])
        row[condition] = result["success"]["overall"]
    recall = cli_json(["eval", str(run / model), "--episodes", str(episodes), "--seeds", seeds])
    row["recall"] = recall["success"]["overall"]
    row["greedy_retrieval"] = recall["greedy_accuracy"]
    return row


def markdown(rows: list[dict[str, Any]]) -> str:
    """Our rows, then the published RememberColor figures, as markdown tables."""
    lines = ["| task | controller | none | wrong | oracle | recall | greedy retrieval | recall / oracle |",
             "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        ratio = f"{row['recall'] / row['oracle']:.2f}" if row["oracle"] > 0 else "-"
        lines.append(f"| {row['task']} | {row['controller']} | {row['none']:.0%} | {row['wrong']:.0%} | "
                     f"{row['oracle']:.0%} | {row['recall']:.0%} | {row['greedy_retrieval']:.0%} | {ratio} |")
    tasks = list(next(iter(PUBLISHED.values())))
    ours = {row["task"]: row["recall"] for row in rows}
    lines += ["", "| system | " + " | ".join(tasks) + " |", "|---|" + "---|" * len(tasks)]
    for system, figures in PUBLISHED.items():
        lines.append(f"| {system} | " + " | ".join(f"{figures[t]}%" for t in tasks) + " |")
    lines.append("| sb3-memret (recall, this run) | " + " | ".join(
        f"{ours[t]:.0%}" if t in ours else "-" for t in tasks) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="recall run folders, one per MIKASA task")
    parser.add_argument("--episodes", type=int, default=50, help="episodes per cell")
    parser.add_argument("--seeds", choices=["dev", "protocol"], default="dev",
                        help="the tasks' development seeds (dev, 5000 + i), or MIKASA's evaluation seeds (protocol, "
                             "4242424242 + i: its test set, for the final figure only)")
    parser.add_argument("--model", default="final_model.zip", help="the model file in each run folder")
    parser.add_argument("--out", type=Path, default=None, help="also write mikasa_table.md and .json here")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    missing = [str(run / args.model) for run in args.runs if not (run / args.model).is_file()]
    if missing:
        parser.error(f"no model file {missing}; pass run folders of `sb3-memret train recall` (or --model)")
    rows = [task_row(run, args.episodes, args.model, args.seeds) for run in args.runs]
    table = markdown(rows)
    print(table)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "mikasa_table.md").write_text(table + "\n")
        (args.out / "mikasa_table.json").write_text(json.dumps({"rows": rows, "published": PUBLISHED}, indent=2))


if __name__ == "__main__":
    main()
