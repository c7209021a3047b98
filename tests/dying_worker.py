"""Jobs for the worker-pool tests: a job that kills its own worker process the first time it is played."""

import os
import signal
from pathlib import Path

MARKERS: Path | None = None


def set_up(markers: str) -> None:
    global MARKERS
    MARKERS = Path(markers)


def square_or_die(job: int) -> int:
    """``job ** 2``; a negative job kills its worker (SIGKILL) the first time, and every time once ``always`` is set."""
    if job < 0:
        marker = MARKERS / f"died-{job}"
        if not marker.exists() or (MARKERS / "always").exists():
            marker.touch()
            os.kill(os.getpid(), signal.SIGKILL)
    return job ** 2
