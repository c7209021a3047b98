"""How a finetune draws its training batches: uniformly, or more often the frames it still gets wrong.

A phase a few frames long (TimedTransfer's set-down: 8% of one task's frames, told apart from the holding frames
around it only by the prompt's count) is drawn as rarely as it occurs, and a policy can reach a low mean loss while
never learning it. With ``priority`` > 0 each training frame is drawn with probability proportional to
``(error + mean error) ** priority``, its error being its action error when it was last drawn (frames not yet drawn
count as the largest error seen, so every frame is visited early): the frames the policy gets wrong are drawn more
often, and an easy frame is still drawn at least about half as often as an average one (the mean error added).
With ``strata`` (a multi-task finetune's task of each frame) the errors rank frames within their stratum only: each
stratum keeps its share of the draws (its share of the frames), so one task's many hard frames take no draws from
the others, and the mean added is the stratum's own.
"""

from __future__ import annotations

import numpy as np


class FrameSampler:
    """Draws batches of training frames (``frames``: their indices) and keeps each frame's last action error;
    ``strata`` (one label per frame, in ``frames``' order; None: one stratum) keep each group's share of the draws."""

    def __init__(self, frames: np.ndarray, priority: float = 0.0, strata: np.ndarray | None = None):
        if priority < 0:
            raise ValueError(f"priority must be >= 0 (0: uniform sampling), got {priority}")
        if len(frames) == 0:
            raise ValueError("a frame sampler needs at least one training frame")
        if strata is not None and len(strata) != len(frames):
            raise ValueError(f"{len(strata)} strata labels for {len(frames)} frames: give one per frame")
        order = np.argsort(frames, kind="stable")
        self.frames = np.asarray(frames)[order]  # a finetune's training split comes sorted: the same draws as from it
        self.priority = float(priority)
        self._strata: np.ndarray | None = None  # each frame's stratum, numbered 0..S-1
        self._sizes: np.ndarray | None = None  # each stratum's frame count
        if strata is not None:
            self._strata = np.unique(np.asarray(strata)[order], return_inverse=True)[1]
            self._sizes = np.bincount(self._strata)
        self.load_state(np.full(len(self.frames), np.nan))

    def draw(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """``size`` distinct frames (all of them when fewer), uniformly or by error."""
        size = min(size, len(self.frames))
        if self.priority == 0:
            return rng.choice(self.frames, size=size, replace=False)
        weights = self.weights()
        picked = np.empty(0, dtype=np.int64)
        while len(picked) < size:  # draw with replacement, keep the distinct ones, top up from the rest
            cdf = np.cumsum(weights)
            drawn = cdf.searchsorted(rng.random(size - len(picked)) * cdf[-1], side="right")
            picked = np.union1d(picked, np.minimum(drawn, len(cdf) - 1))
            weights[picked] = 0.0
        return self.frames[picked]

    def weights(self) -> np.ndarray:
        """Each frame's unnormalised chance of being drawn: ``(error + mean error) ** priority``, a frame not drawn
        yet counting the largest error seen (1 before any); with strata, the mean is the stratum's and each stratum's
        weights sum to its frame count."""
        if self._strata is None:
            return (self._filled + self._filled.mean() + 1e-12) ** self.priority
        means = np.bincount(self._strata, self._filled) / self._sizes
        weights = (self._filled + means[self._strata] + 1e-12) ** self.priority
        return weights * (self._sizes / np.bincount(self._strata, weights))[self._strata]

    def probabilities(self) -> np.ndarray:
        """``weights``, normalised."""
        weights = self.weights()
        return weights / weights.sum()

    def update(self, frames: np.ndarray, errors: np.ndarray) -> None:
        """Record the action errors of ``frames`` (drawn by ``draw``); a uniform sampler keeps none."""
        if self.priority == 0:
            return
        if len(frames) != len(errors):
            raise ValueError(f"{len(frames)} frames but {len(errors)} errors")
        at = np.searchsorted(self.frames, frames)
        if (at >= len(self.frames)).any() or (self.frames[np.minimum(at, len(self.frames) - 1)] != frames).any():
            raise ValueError("errors given for frames outside the training split")
        first = self._largest is None
        self._unseen[at] = False
        self._filled[at] = errors
        if len(errors) and (first or np.max(errors) > self._largest):  # frames not drawn yet: the largest seen
            self._largest = float(np.max(errors))
            self._filled[self._unseen] = self._largest

    def state(self) -> np.ndarray:
        """What a resumed finetune restores (``load_state``): the frames' last errors (NaN: not drawn yet)."""
        return np.where(self._unseen, np.nan, self._filled)

    def load_state(self, errors: np.ndarray) -> None:
        """Restore the errors ``state`` gave; a ValueError when they are of another training split."""
        errors = np.asarray(errors, dtype=float)
        if errors.shape != self.frames.shape:
            raise ValueError(f"the saved frame errors are for {errors.shape[0]} training frames, this split has "
                             f"{self.frames.shape[0]}")
        self._unseen = np.isnan(errors)
        self._largest = float(errors[~self._unseen].max()) if (~self._unseen).any() else None  # None: none seen
        self._filled = np.where(self._unseen, 1.0 if self._largest is None else self._largest, errors)


__all__ = ["FrameSampler"]
