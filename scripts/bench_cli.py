"""How fast the command line answers: ``sb3-memret --help`` and one-line argument errors, each a fresh process,
against a bare Python start-up (``python -c pass``) measured in the same run, and the heavy libraries the
answer loaded (none of torch, ManiSkill, lerobot, sentence-transformers should load before a command needs them).

Usage: ``python scripts/bench_cli.py [--runs 7]``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

CLI = str(Path(sys.executable).parent / "sb3-memret")  # the console script beside this interpreter
HEAVY = ("torch", "mani_skill", "lerobot", "sentence_transformers")
COMMANDS = {
    "python -c pass (baseline)": [sys.executable, "-c", "pass"],
    "sb3-memret --help": [CLI, "--help"],
    "sb3-memret train --help": [CLI, "train", "--help"],
    "train recall --n-envs 0 (an error)": [CLI, "train", "recall", "--n-envs", "0"],
    "rollout --task nope (an error)": [CLI, "rollout", "--task", "nope"],
}


def wall_seconds(command: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(command, capture_output=True, check=False)
    return time.perf_counter() - start


def loaded_heavy(args: list[str]) -> list[str]:
    """The heavy libraries in sys.modules after the CLI answered ``args``."""
    code = ("import sys\nfrom sb3_memret.cli import main\ntry:\n    main(%r)\nexcept SystemExit:\n    pass\n"
            "print('loaded:' + ','.join(m for m in %r if m in sys.modules))" % (args, HEAVY))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    line = next((line for line in out.stdout.splitlines() if line.startswith("loaded:")), None)
    if line is None:
        raise RuntimeError(f"the CLI check of {args} failed: {out.stderr[-500:]}")
    return [m for m in line.removeprefix("loaded:").split(",") if m]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7, help="timed runs of each command (after one warm-up)")
    runs = parser.parse_args().runs
    times = {name: [] for name in COMMANDS}
    for name, command in COMMANDS.items():
        wall_seconds(command)  # warm the file cache
    for _ in range(runs):  # interleaved, so a drift of the machine's speed hits every command alike
        for name, command in COMMANDS.items():
            times[name].append(wall_seconds(command))
    base = statistics.median(times["python -c pass (baseline)"])
    print("| command | median s | min s | max s | over bare Python start-up | heavy libraries loaded |")
    print("|---|---|---|---|---|---|")
    for name, command in COMMANDS.items():
        median = statistics.median(times[name])
        heavy = "-" if name.startswith("python") else (", ".join(loaded_heavy(command[1:])) or "none")
        print(f"| {name} | {median:.2f} | {min(times[name]):.2f} | {max(times[name]):.2f} | {median / base:.1f}x | {heavy} |")


if __name__ == "__main__":
    main()
