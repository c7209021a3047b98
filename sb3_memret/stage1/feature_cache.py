"""Frozen-trunk features of demonstration frames, cached on disk per dataset.

A frozen trunk's features depend only on the frames, so each dataset's are computed once and read back by every
later finetune (another seed, a per-task and a multi-task policy over the same chunks). On this 2-core CPU
EfficientNet-Lite0 takes minutes for a few thousand episodes' frames, more than the heads' training on them. Files
are named by the trunk (its class and weights' SHA-256) and by the SHA-256 of the frames themselves, so an edited
dataset or another trunk never reads stale features; they live under ``cache_root()/trunk-features`` and are safe to
delete.
"""

from __future__ import annotations

import hashlib
import warnings
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from sb3_memret.common.cache import CACHE_ENV, cache_root, write_atomically

FOLDER = "trunk-features"


def trunk_id(trunk: torch.nn.Module) -> str:
    """A name for a frozen trunk's features: its class (or its ``cache_name``, which says where it is cut) and the
    first 16 hex digits of its weights' SHA-256."""
    digest = getattr(trunk, "sha256", None)
    if not digest:
        raise ValueError(f"{type(trunk).__name__} has no weights checksum (sha256); its features cannot be cached")
    return f"{getattr(trunk, 'cache_name', type(trunk).__name__)}-{digest[:16]}"


def frames_digest(frames: np.ndarray) -> str:
    """SHA-256 of an image array's shape, dtype and bytes."""
    digest = hashlib.sha256(f"{frames.shape}{frames.dtype}".encode())
    digest.update(np.ascontiguousarray(frames).data)
    return digest.hexdigest()


def cached_features(trunk: torch.nn.Module, frames: np.ndarray, spans: Sequence[int],
                    compute: Callable[[np.ndarray], torch.Tensor], root: Path | None = None) -> torch.Tensor:
    """``compute(frames)`` (a trunk's float16 features of uint8 frames), computed dataset by dataset (``spans``: each
    dataset's frame count, in order) and read from the cache where an earlier finetune left them. A cache that
    cannot be written is warned about, naming the folder, and the features are still returned."""
    if sum(spans) != len(frames):
        raise ValueError(f"the datasets' spans {list(spans)} cover {sum(spans)} frames, not the {len(frames)} given")
    folder = (root or cache_root()) / FOLDER / trunk_id(trunk)
    channels = getattr(trunk, "out_channels", None)
    parts, start = [], 0
    for span in spans:
        block = frames[start: start + span]
        start += span
        path = folder / f"{frames_digest(block)}.npy"
        if path.is_file():
            cached = np.load(path)
            if len(cached) == span and (channels is None or cached.shape[1] == channels):
                parts.append(torch.from_numpy(cached))
                continue  # else written by a trunk of another shape under the same weights: made afresh below
        features = compute(block)
        _save(path, features.numpy())
        parts.append(features)
    return torch.cat(parts)


def _save(path: Path, array: np.ndarray) -> None:
    """Write ``array`` to ``path`` atomically (a finetune stopped midway leaves no half file)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(path, lambda f: np.save(f, array))
    except OSError as err:
        warnings.warn(f"trunk features not cached: {path.parent} cannot be written ({err}); set ${CACHE_ENV} to a "
                      "writable folder to keep them for the next finetune", stacklevel=3)


__all__ = ["FOLDER", "cached_features", "frames_digest", "trunk_id"]
