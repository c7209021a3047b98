"""MIKASA-Robo-VLA's lamp bulb mesh, which ``mikasa-robo-suite==1.0.0`` leaves out of its wheel and source
distribution: every env that builds a lamp (``mikasa_robo_suite.vla.utils.shapes.build_color_switch_lamp``: the
BlinkCountButtonPress tasks among them) fails at its first reset with "cannot make canonical path ...
low_poly_light_bulb.glb".

The project ships MIKASA's file (``assets/low_poly_light_bulb.glb``, byte-identical to the one in MIKASA-Robo's git
tag v1.0.0: ``LAMP_SHA256``; CC BY 4.0, ``assets/README.md``), and ``install_lamp_asset`` copies it to where MIKASA
looks for it, inside the installed package, checking the digest on both ends. The lamp tasks call it before making
their env, and the task registry whenever one is named (``ensure_lamp_asset``), so MIKASA's own harness, which makes
its envs itself, finds the mesh too.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import tempfile
from pathlib import Path

LAMP_FILE = "low_poly_light_bulb.glb"
LAMP_SHA256 = "cc66bda617401ce47bf4bd69e297c226b909d2bb532a5ff57721ee75d6d4aca5"
SHIPPED_LAMP = Path(__file__).resolve().parents[1] / "assets" / LAMP_FILE


def mikasa_lamp_path() -> Path | None:
    """Where MIKASA's ``build_color_switch_lamp`` loads the bulb from (``vla/utils/objects/`` in its package), or
    None when ``mikasa-robo-suite`` is not installed; found without importing MIKASA (which imports ManiSkill)."""
    spec = importlib.util.find_spec("mikasa_robo_suite")
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations))) / "vla" / "utils" / "objects" / LAMP_FILE


def _is_mikasas(path: Path) -> bool:
    return path.is_file() and hashlib.sha256(path.read_bytes()).hexdigest() == LAMP_SHA256


def install_lamp_asset() -> Path:
    """Put MIKASA's bulb mesh where MIKASA loads it from, if it is not there yet (an atomic copy of the shipped file,
    its digest checked), and return that path; a RuntimeError says why it cannot (MIKASA not installed among
    the reasons)."""
    target = mikasa_lamp_path()
    if target is None:
        raise RuntimeError("MIKASA's lamp needs mikasa-robo-suite, which is not installed")
    if _is_mikasas(target):
        return target
    missing = f"MIKASA's lamp bulb mesh is missing at {target} (mikasa-robo-suite 1.0.0 does not ship it)"
    if not _is_mikasas(SHIPPED_LAMP):
        raise RuntimeError(f"{missing}, and the project's copy {SHIPPED_LAMP} is missing or not MIKASA's file")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        descriptor, partial = tempfile.mkstemp(prefix=f".{LAMP_FILE}.", dir=target.parent)
    except OSError as err:
        raise RuntimeError(f"{missing}, and it cannot be copied there ({err}): copy {SHIPPED_LAMP} there") from None
    os.close(descriptor)
    try:
        shutil.copyfile(SHIPPED_LAMP, partial)
        if not _is_mikasas(Path(partial)):
            raise RuntimeError(f"{missing}, and copying {SHIPPED_LAMP} there changed its bytes")
        os.chmod(partial, 0o644)
        os.replace(partial, target)
    finally:
        Path(partial).unlink(missing_ok=True)
    return target


def ensure_lamp_asset() -> str | None:
    """``install_lamp_asset`` as the task registry's availability check: None when the mesh is in place (or MIKASA
    is not installed: importing its envs then says so), else the line saying why it cannot be."""
    if mikasa_lamp_path() is None:
        return None
    try:
        install_lamp_asset()
    except RuntimeError as err:
        return str(err)
    return None


__all__ = ["LAMP_SHA256", "SHIPPED_LAMP", "ensure_lamp_asset", "install_lamp_asset", "mikasa_lamp_path"]
