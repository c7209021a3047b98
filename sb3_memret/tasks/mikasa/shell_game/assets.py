"""The YCB mug the ShellGame envs build: where ManiSkill keeps it, and why a task cannot run without it."""

from __future__ import annotations

import os
from pathlib import Path


YCB_DIR = "assets/mani_skill2_ycb"  # ManiSkill's "ycb" data source, under its ASSET_DIR

MUG_FILES = ("info_pick_v0.json", "models/025_mug/collision.ply", "models/025_mug/textured.obj")

DOWNLOAD_HINT = "python -m mani_skill.utils.download_asset ycb"

def maniskill_asset_dir() -> Path:
    """ManiSkill's ASSET_DIR as ``mani_skill/__init__.py`` sets it ($MS_ASSET_DIR/data, else ~/.maniskill/data),
    read without importing ManiSkill, whose import builds every env (seconds)."""
    return Path(os.getenv("MS_ASSET_DIR", os.path.join(os.path.expanduser("~"), ".maniskill"))) / "data"



def ycb_mug_missing() -> str | None:
    """Why the ShellGame tasks cannot run here (the first file of the YCB mug that ManiSkill lacks, and how to
    get it), or None when ManiSkill has the mug."""
    root = maniskill_asset_dir() / YCB_DIR
    missing = next((root / name for name in MUG_FILES if not (root / name).is_file()), None)
    if missing is None:
        return None
    return (f"MIKASA's ShellGame tasks need ManiSkill's YCB mug model, missing at {missing}; get it with "
            f"`{DOWNLOAD_HINT}`, or set MS_ASSET_DIR to a folder whose data/{YCB_DIR} has it")


__all__ = ["DOWNLOAD_HINT", "MUG_FILES", "YCB_DIR", "maniskill_asset_dir", "ycb_mug_missing"]
