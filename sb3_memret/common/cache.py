"""The project's on-disk cache: derived files that are costly to make and safe to delete (the light Panda's meshes,
frozen-trunk features of demonstration frames), and the atomic write such files (and a finetune's state) go through."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable

CACHE_ENV = "SB3_MEMRET_CACHE"


def cache_root() -> Path:
    """``$SB3_MEMRET_CACHE``, else ``~/.cache/sb3-memret``."""
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "sb3-memret")


def write_atomically(path: Path, write: Callable[[BinaryIO], None]) -> None:
    """``write`` into a file beside ``path``, then renamed onto it: a process stopped midway leaves the previous file
    (or none), never half of one. ``path``'s folder must exist; an OSError goes to the caller."""
    handle, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as f:
            write(f)
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)


__all__ = ["CACHE_ENV", "cache_root", "write_atomically"]
