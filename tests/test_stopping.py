"""`sb3-memret train` stopped from outside, as a cluster would: SIGTERM to the whole process group, and an
physics worker killed (what the out-of-memory killer does). Both keep a checkpoint, say how to resume, and
print no traceback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from sb3_memret.callbacks import latest_checkpoint
from sb3_memret.policy.ppo import load_model

CONFIG = """\
sb3_memret/DrawerRecall-v0:
  n_timesteps: 100000
  n_envs: 2
  n_steps: 8
  batch_size: 8
  n_epochs: 1
  env_kwargs:
    max_control_steps: 48
"""


def start_training(tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    (tmp_path / "config.yml").write_text(CONFIG)
    out = tmp_path / "run"
    command = [str(Path(sys.executable).parent / "sb3-memret"), "train", "recall", "--config", str(tmp_path / "config.yml"),
               "--out", str(out), "--eval-episodes", "1", "--eval-every", "1000", "--no-progress"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)  # its own process group, as a scheduler's job
    deadline = time.monotonic() + 240
    while latest_checkpoint(out / "checkpoints") is None:  # a round has finished: training is under way
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"training did not get going: {process.communicate()}")
        time.sleep(0.5)
    return process, out


def env_workers(pid: int) -> list[psutil.Process]:
    """The spawned physics worker processes of the trainer ``pid`` (not its resource tracker)."""
    return [p for p in psutil.Process(pid).children() if "spawn_main" in " ".join(p.cmdline())]


def finish(process: subprocess.Popen) -> tuple[int, str]:
    try:
        _, stderr = process.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        pytest.fail(f"training did not stop: {process.communicate()}")
    return process.returncode, stderr


def assert_resumable(out: Path, stderr: str) -> None:
    assert "Traceback" not in stderr, stderr
    assert f"continue with sb3-memret train recall --out {out} --resume" in stderr
    checkpoint = latest_checkpoint(out / "checkpoints")
    assert checkpoint is not None and load_model(checkpoint).num_timesteps > 0
    assert not (out / "final_model.zip").exists()


def test_sigterm_to_the_job_checkpoints_and_shuts_down_cleanly(tmp_path):
    process, out = start_training(tmp_path)
    workers = env_workers(process.pid)
    os.killpg(process.pid, signal.SIGTERM)
    code, stderr = finish(process)
    assert code == 143 and "stopped by SIGTERM: saved" in stderr, stderr
    assert_resumable(out, stderr)
    assert len(workers) == 4 and not psutil.wait_procs(workers, timeout=10)[1]  # every worker has exited


def test_a_killed_physics_worker_is_named_and_the_run_can_resume(tmp_path):
    process, out = start_training(tmp_path)
    workers = env_workers(process.pid)
    assert len(workers) == 4  # training and held-out envs, two each
    workers[0].kill()
    code, stderr = finish(process)
    assert code == 1, stderr
    assert f"(pid {workers[0].pid}) killed by SIGKILL" in stderr and "stopped by physics worker" in stderr, stderr
    assert_resumable(out, stderr)
