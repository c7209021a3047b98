"""Strict checks that a checkpoint's tensors really are in a model, by name, shape and value.

Loaders that warn and carry on (lerobot's ``PI05Policy.from_pretrained`` returns a randomly
initialised model when its weights fail to load; peft ignores adapter tensors whose module
names do not match) leave a model that runs but is not the finetuned one. These checks compare
what the model holds after loading with what the files hold, and raise naming every difference.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import torch

from sb3_memret.common.errors import WeightsNotLoadedError

SHOWN = 8  # names listed per kind of difference in an error


@dataclass(frozen=True)
class LoadReport:
    """How a model's tensors differ from the saved ones (each a sorted tuple of names)."""

    missing: tuple[str, ...]  # in the model, not in the files: left at initialisation
    unexpected: tuple[str, ...]  # in the files, not in the model: silently dropped
    mismatched: tuple[str, ...]  # in both, with different shapes
    differing: tuple[str, ...]  # in both, same shape, other values: not loaded

    @property
    def ok(self) -> bool:
        return not (self.missing or self.unexpected or self.mismatched or self.differing)

    def describe(self) -> str:
        parts = []
        for kind in ("missing", "unexpected", "mismatched", "differing"):
            names = getattr(self, kind)
            if names:
                more = f" and {len(names) - SHOWN} more" if len(names) > SHOWN else ""
                parts.append(f"{len(names)} {kind}: {', '.join(names[:SHOWN])}{more}")
        return "; ".join(parts)


def compare_tensors(held: Mapping[str, torch.Tensor], saved: Mapping[str, torch.Tensor]) -> LoadReport:
    """Compare the tensors a model holds with the saved ones, value for value.

    A saved tensor is cast to the held tensor's dtype first (loading casts the same way). A held
    name missing from ``saved`` is fine when it shares storage with a held name that is saved:
    tied weights (PaliGemma's ``lm_head`` and ``embed_tokens``) are stored once.
    """
    storage = {name: _storage_key(t) for name, t in held.items()}
    saved_storage = {storage[name] for name in held.keys() & saved.keys()}
    missing = [n for n in held.keys() - saved.keys() if storage[n] not in saved_storage]
    mismatched, differing = [], []
    for name in held.keys() & saved.keys():
        h, s = held[name], saved[name]
        if h.shape != s.shape:
            mismatched.append(f"{name} {tuple(s.shape)}->{tuple(h.shape)}")
        elif not torch.equal(h.detach().cpu(), s.detach().cpu().to(h.dtype)):
            differing.append(name)
    return LoadReport(*(tuple(sorted(x)) for x in (missing, saved.keys() - held.keys(), mismatched, differing)))


def check_loaded(held: Mapping[str, torch.Tensor], saved: Mapping[str, torch.Tensor], what: str) -> None:
    """Raise WeightsNotLoadedError naming every difference unless ``held`` is exactly ``saved``."""
    if not saved:
        raise WeightsNotLoadedError(f"{what} holds no tensors")
    report = compare_tensors(held, saved)
    if not report.ok:
        raise WeightsNotLoadedError(f"{what} was not loaded as saved: {report.describe()}")


def _storage_key(t: torch.Tensor) -> tuple:
    return (t.untyped_storage().data_ptr(), t.storage_offset(), tuple(t.shape))
