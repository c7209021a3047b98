"""Errors whose message says what is missing and what to do: the CLI prints each as one line.

They live apart from the modules that raise them (which load torch, ManiSkill or SAPIEN), so the
CLI can catch them without loading those libraries first.
"""

from __future__ import annotations


class WeightsNotLoadedError(RuntimeError):
    """A model does not hold the tensors its checkpoint or adapter files hold."""


class RendererNotFoundError(RuntimeError):
    """No software Vulkan driver SAPIEN can use, with the command that installs one."""


class CudaNotFoundError(RuntimeError):
    """GPU simulation was asked for on a machine where torch finds no CUDA device."""


class RunFolderError(ValueError):
    """A saved run's configuration cannot be read here (a task of one's own whose module is not on PYTHONPATH, a
    value no longer accepted)."""


__all__ = ["CudaNotFoundError", "RendererNotFoundError", "RunFolderError", "WeightsNotLoadedError"]
