"""scripts/record_task_demos.sh, the multitask controller's resumable recording, run against a stand-in for
``sb3-memret demos`` that logs its calls: every chunk recorded once, in order, however many recorders share the
folder, and a rerun records only the missing chunks."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "record_task_demos.sh"

FAKE_DEMOS = """#!/bin/bash
# stands in for `sb3-memret demos`: logs TASK SEED, takes a moment, fails for a task named Broken
task=$3 seed=$7
echo "start" >> "$CALLS.events"
echo "$task $seed" >> "$CALLS"
sleep 0.3
echo "end" >> "$CALLS.events"
[ "$task" != Broken ] || exit 1
"""


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    """A copy of the script in a tree of its own, whose .venv/bin/sb3-memret is the stand-in."""
    (tmp_path / "scripts").mkdir()
    shutil.copy(SCRIPT, tmp_path / "scripts" / SCRIPT.name)
    fake = tmp_path / ".venv" / "bin" / "sb3-memret"
    fake.parent.mkdir(parents=True)
    fake.write_text(FAKE_DEMOS)
    fake.chmod(0o755)
    return tmp_path


def record(tree: Path, *tasks: str, episodes: int = 150, jobs: int = 1) -> subprocess.CompletedProcess:
    env = {**os.environ, "CALLS": str(tree / "calls.txt"), "JOBS": str(jobs)}
    return subprocess.run(["bash", str(tree / "scripts" / SCRIPT.name), "out", str(episodes), *tasks],
                          cwd=tree, env=env, capture_output=True, text=True, timeout=60)


def calls(tree: Path) -> list[tuple[str, int]]:
    path = tree / "calls.txt"
    return [(t, int(s)) for t, s in (line.split() for line in path.read_text().splitlines())] if path.exists() else []


@pytest.mark.parametrize("jobs", [1, 3])
def test_every_chunk_is_recorded_once_however_many_recorders(tree: Path, jobs: int):
    done = record(tree, "A", "B", jobs=jobs)
    assert done.returncode == 0, done.stderr
    expected = {(task, 100000 + 50 * i) for i in range(3) for task in ("A", "B")}
    assert sorted(calls(tree)) == sorted(expected)  # each chunk once, with its own seeds
    assert all((tree / "out" / task / f"chunk{i}.done").is_file() for task in ("A", "B") for i in range(3))
    if jobs == 1:  # one recorder: chunk i of every task before chunk i + 1 of any
        assert calls(tree) == [(t, 100000 + 50 * i) for i in range(3) for t in ("A", "B")]
    assert most_at_once(tree) == min(jobs, 6) if jobs == 1 else most_at_once(tree) > 1  # the recorders overlap


def most_at_once(tree: Path) -> int:
    """The most chunks being recorded at one moment, from the stand-in's start and end events."""
    running = peak = 0
    for event in (tree / "calls.txt.events").read_text().split():
        running += 1 if event == "start" else -1
        peak = max(peak, running)
    return peak


def test_a_rerun_records_only_the_missing_chunks(tree: Path):
    assert record(tree, "A", episodes=100).returncode == 0
    (tree / "out" / "A" / "chunk1.done").unlink()  # as if stopped while recording chunk 1
    (tree / "calls.txt").unlink()
    assert record(tree, "A", episodes=150, jobs=2).returncode == 0
    assert sorted(calls(tree)) == [("A", 100050), ("A", 100100)]


def test_a_chunk_that_fails_fails_the_recording_and_is_not_marked_done(tree: Path):
    done = record(tree, "Broken", "A", episodes=50)
    assert done.returncode != 0
    assert not (tree / "out" / "Broken" / "chunk0.done").exists()
    (tree / ".venv" / "bin" / "sb3-memret").write_text(FAKE_DEMOS.replace("Broken", "Nothing"))  # mended
    assert record(tree, "Broken", "A", episodes=50).returncode == 0
    assert (tree / "out" / "Broken" / "chunk0.done").is_file() and (tree / "out" / "A" / "chunk0.done").is_file()


def test_prompt_mix_reaches_every_chunks_demos_call_and_is_left_out_unset(tree: Path):
    fake = tree / ".venv" / "bin" / "sb3-memret"
    fake.write_text('#!/bin/bash\necho "$@" >> "$CALLS.args"\n')
    mix = "bare=0.2,matching=0.5,mismatched=0.1,recalled=0.2"
    for prompt_mix in (mix, None):
        env = {k: v for k, v in os.environ.items() if k != "PROMPT_MIX"} | {"CALLS": str(tree / "calls.txt")}
        if prompt_mix:
            env["PROMPT_MIX"] = prompt_mix
        shutil.rmtree(tree / "out", ignore_errors=True)
        done = subprocess.run(["bash", str(tree / "scripts" / SCRIPT.name), "out", "100", "A"], cwd=tree, env=env,
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
    lines = (tree / "calls.txt.args").read_text().splitlines()
    assert len(lines) == 4 and all(f"--prompt-mix {mix}" in line for line in lines[:2])
    assert not any("--prompt-mix" in line for line in lines[2:])
