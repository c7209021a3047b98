"""Where the main job's wall time goes: `sb3-memret train recall --report`, timed as a whole and split by phase.

Runs the job as a user does (a fresh process), then reads the split the run recorded in its ``summary.json``
(``seconds``: envs and model set up, training decisions collected, PPO updates, each held-out evaluation, and the
report's learning curves, oracle and no-memory baselines and trace) and prints it beside the process's own wall
time; what is left over is the process's start (imports, the controller's weights, MiniLM) and its exit.
``--against FILE`` plays the same job with another zoo config first and prints each phase's ratio to it.

Usage: ``python scripts/bench_main_job.py [--config FILE] [--against FILE] [--seed 0] [--out runs/bench-main-job]``
(``--from RUN ...``: print the split of finished runs without playing anything).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

SB3_MEMRET = Path(sys.executable).with_name("sb3-memret")


def play(config: Path | None, seed: int, out: Path) -> float:
    """Run the main job into ``out`` (removed first) and return its wall seconds."""
    shutil.rmtree(out, ignore_errors=True)
    args = [str(SB3_MEMRET), "train", "recall", "--report", "--seed", str(seed), "--out", str(out)]
    if config is not None:
        args += ["--config", str(config)]
    start = time.perf_counter()
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def split(run: Path, wall: float | None) -> dict[str, float]:
    """The phases of the run in ``run``, in seconds; ``wall`` (the whole process) adds start-up and exit."""
    summary = json.loads((run / "summary.json").read_text())
    seconds: dict[str, Any] = summary.get("seconds") or {}
    if not seconds:
        raise SystemExit(f"{run}/summary.json records no seconds: a run from before sb3-memret timed its phases")
    report = seconds.get("report", {})
    phases = {"set-up (envs, workers, model)": seconds["setup"],
              f"training decisions ({summary['num_timesteps']})": seconds["collect"],
              f"PPO updates ({summary['rounds']} rounds)": seconds["update"]}
    for round_, value in seconds["evaluate_by_round"].items():
        phases[f"held-out evaluation, round {round_}"] = value
    rounds = len(seconds["evaluate_by_round"])
    phases[f"held-out evaluations, all ({rounds})"] = seconds["evaluate"]
    phases.update({f"report: {name}": value for name, value in report.items()})
    measured = sum(value for key, value in phases.items() if not key.startswith("held-out evaluations, all"))
    if wall is not None:
        phases["start-up and exit (imports, weights, MiniLM)"] = wall - measured
        phases["total"] = wall
    else:
        phases["total (without start-up and exit)"] = measured
    phases["decisions/s while training"] = summary["num_timesteps"] / max(seconds["collect"] + seconds["update"], 1e-9)
    return phases


def print_split(name: str, phases: dict[str, float], baseline: dict[str, float] | None) -> None:
    print(f"\n{name}")
    width = max(map(len, phases))
    for key, value in phases.items():
        line = f"  {key:<{width}}  {value:8.1f}"
        if baseline is not None:
            same = [k for k in baseline if k.split(" (")[0].split(",")[0] == key.split(" (")[0].split(",")[0]]
            if len(same) == 1 and baseline[same[0]] > 0:
                line += f"   {value / baseline[same[0]]:5.2f}x the baseline's {baseline[same[0]]:.1f}"
        print(line)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, default=None, help="zoo config [default: the drawer's shipped one]")
    parser.add_argument("--against", type=Path, default=None, help="a baseline zoo config, played first")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/bench-main-job"))
    parser.add_argument("--from", dest="runs", type=Path, nargs="+", default=None,
                        help="finished run folders to split instead of playing (the first is the baseline)")
    args = parser.parse_args()
    if args.runs:
        splits = [(str(run), split(run, None)) for run in args.runs]
    else:
        splits = []
        if args.against is not None:
            wall = play(args.against, args.seed, args.out / "baseline")
            splits.append((f"baseline: {args.against}", split(args.out / "baseline", wall)))
        wall = play(args.config, args.seed, args.out / "job")
        splits.append((f"main job: {args.config or 'zoo_configs/memret_ppo.yml'}", split(args.out / "job", wall)))
    baseline = splits[0][1] if len(splits) > 1 else None
    for index, (name, phases) in enumerate(splits):
        print_split(name, phases, baseline if index else None)


if __name__ == "__main__":
    main()
