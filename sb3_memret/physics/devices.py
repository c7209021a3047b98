"""What a machine must have for the GPU paths: a CUDA device, checked before ManiSkill looks for one.

Without it ManiSkill's GPU simulation fails deep inside SAPIEN (``failed to find device "cuda"``); the
check names what is missing and what to use instead, in one line.
"""

from __future__ import annotations

from sb3_memret.common.errors import CudaNotFoundError


def check_cuda(what: str = "the gpu physics backend (ManiSkill's GPU simulation)") -> None:
    """Raise ``CudaNotFoundError`` naming ``what`` when torch finds no CUDA device."""
    import torch

    if not torch.cuda.is_available():
        raise CudaNotFoundError(f"{what} needs a CUDA GPU, and torch finds none on this machine; use --backend process "
                                "(one CPU worker per env) or auto")


__all__ = ["CudaNotFoundError", "check_cuda"]
