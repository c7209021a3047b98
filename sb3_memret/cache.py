"""The project's on-disk cache: derived files that are costly to make and safe to delete (the light Panda's meshes,
frozen-trunk features of demonstration frames)."""

from __future__ import annotations

import os
from pathlib import Path

CACHE_ENV = "SB3_MEMRET_CACHE"


def cache_root() -> Path:
    """``$SB3_MEMRET_CACHE``, else ``~/.cache/sb3-memret``."""
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "sb3-memret")


__all__ = ["CACHE_ENV", "cache_root"]
