"""Batched observation trees (nested mappings of arrays or tensors, one row per env): to NumPy, one env's
slice, several envs stacked. What tasks, physics backends and rollouts share to move observations about."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np


def _mapping(tree: Mapping[str, Any], items: dict[str, Any]) -> dict[str, Any]:
    """``items`` as a mapping of ``tree``'s own kind where that kind asks to be kept (``keeps_kind``: the benchmark's
    policy-side view, which refuses a missing key by naming what the harness gives), else a dict."""
    return type(tree)(items) if getattr(type(tree), "keeps_kind", False) else items


def to_numpy(tree: Any) -> Any:
    """A nested observation with every tensor as a numpy array (cheap to pickle, device-free)."""
    if isinstance(tree, Mapping):
        return _mapping(tree, {key: to_numpy(value) for key, value in tree.items()})
    return tree.detach().cpu().numpy() if hasattr(tree, "detach") else np.asarray(tree)


def stack_obs(frames: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Batch-of-one observations concatenated into one batched observation, in the given order."""
    first = frames[0]
    if isinstance(first, Mapping):
        return _mapping(first, {key: stack_obs([frame[key] for frame in frames]) for key in first})
    return np.concatenate(frames, axis=0)


def select_obs(tree: Any, index: int) -> Any:
    """Env ``index`` of a batched observation, keeping a batch dimension of one."""
    if isinstance(tree, Mapping):
        return _mapping(tree, {key: select_obs(value, index) for key, value in tree.items()})
    return tree[index:index + 1]


__all__ = ["select_obs", "stack_obs", "to_numpy"]
