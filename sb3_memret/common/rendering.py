"""Camera rendering on a CPU: point SAPIEN's Vulkan at the project's lavapipe.

SAPIEN renders through Vulkan. On a machine without a GPU the software driver lavapipe
serves, but Debian 12's (Mesa 22.3) lacks an extension SAPIEN needs, so ``make renderer``
(``scripts/install_lavapipe.sh``) unpacks Mesa 25's into ``.renderer/``. The Vulkan loader
reads ``VK_ICD_FILENAMES`` when SAPIEN first asks for a device, and the driver's libraries
resolve by soname against what is already loaded, so setting the variable and preloading
them from Python works without a wrapper script or ``LD_LIBRARY_PATH``.
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

from sb3_memret.common.errors import RendererNotFoundError

RENDERER_DIR_ENV = "SB3_MEMRET_RENDERER_DIR"
DEFAULT_RENDERER_DIR = Path(__file__).resolve().parents[2] / ".renderer"
INSTALL_COMMAND = f"make renderer  (or: bash scripts/install_lavapipe.sh {DEFAULT_RENDERER_DIR})"
# Loaded before the driver in this order, so its DT_NEEDED entries find them by soname.
PRELOAD = ("libLLVM-15.so.1", "libdrm.so.2", "libdrm_amdgpu.so.1")


def renderer_dir() -> Path:
    """Where the lavapipe of ``make renderer`` lives (``$SB3_MEMRET_RENDERER_DIR`` overrides)."""
    return Path(os.environ.get(RENDERER_DIR_ENV, DEFAULT_RENDERER_DIR))


def use_cpu_renderer() -> Path:
    """Make SAPIEN render with lavapipe; return the ICD manifest in use.

    A ``VK_ICD_FILENAMES`` set by the user wins. Call it before the first render device is
    created in this process (``make_task_env`` does for ``render_backend="cpu"``).
    """
    chosen = os.environ.get("VK_ICD_FILENAMES")
    if chosen:
        missing = [p for p in chosen.split(os.pathsep) if not Path(p).is_file()]
        if missing:
            raise RendererNotFoundError(f"VK_ICD_FILENAMES names {missing}, which do not exist; unset it to use "
                                        f"the project's lavapipe ({INSTALL_COMMAND})")
        return Path(chosen.split(os.pathsep)[0])
    folder = renderer_dir()
    manifest = folder / "lvp_icd.json"
    if not manifest.is_file():
        raise RendererNotFoundError(
            f"render_backend='cpu' needs a software Vulkan driver (Mesa >= 24.3 lavapipe) and {manifest} does not "
            f"exist; install it with: {INSTALL_COMMAND}")
    lib = folder / "root" / "usr" / "lib" / "x86_64-linux-gnu"
    for name in PRELOAD:
        if (lib / name).is_file():
            ctypes.CDLL(str(lib / name), mode=ctypes.RTLD_GLOBAL)
    os.environ["VK_ICD_FILENAMES"] = str(manifest)
    return manifest


__all__ = ["INSTALL_COMMAND", "RendererNotFoundError", "renderer_dir", "use_cpu_renderer"]
