"""Which demonstrations to record: each episode's seed, prompt kind, arm noise and reset options.

A plan is the task's (``Task.plan_demos``): by default each episode's prompt kind is drawn by ``PromptMix`` (the bare
instruction, the task's true facts, or facts naming something else) and the recorder words the facts from the
episode's ground truth. A task that chooses its episodes' groups itself (the drawer: the target's layer, cycled) sets
``reset_options``, and may name the facts outright (``DemoEpisode.facts``). Recording is ``sb3_memret.stage1.demos``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

PROMPT_KINDS = ("bare", "matching", "mismatched")


@dataclass(frozen=True)
class PromptMix:
    """How episodes' prompts are drawn: bare, the true facts, facts naming something else."""

    bare: float = 0.2
    matching: float = 0.6
    mismatched: float = 0.2

    def __post_init__(self) -> None:
        weights = (self.bare, self.matching, self.mismatched)
        if min(weights) < 0 or not np.isclose(sum(weights), 1.0):
            raise ValueError(f"prompt mix {weights} must be non-negative and sum to 1")

    @property
    def weights(self) -> list[float]:
        """The probabilities of ``PROMPT_KINDS``, in order."""
        return [self.bare, self.matching, self.mismatched]


@dataclass(frozen=True)
class DemoEpisode:
    """One demonstration to record: the env seed, which prompt it gets, the action noise on the arm, the reset
    options that choose its group (none: the env draws it), and the facts its prompt carries when the plan names
    them (None: the task's true facts for ``matching``, its wrong ones for ``mismatched``, none for ``bare``)."""

    seed: int
    prompt_kind: str
    noise: float = 0.0
    reset_options: Mapping[str, Any] = field(default_factory=dict)
    facts: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if self.prompt_kind not in PROMPT_KINDS:
            raise ValueError(f"unknown prompt kind {self.prompt_kind!r}; expected one of {list(PROMPT_KINDS)}")
        if self.noise < 0:
            raise ValueError(f"noise must be >= 0, got {self.noise}")
        if self.prompt_kind == "bare" and self.facts:
            raise ValueError(f"a bare prompt carries no facts, got {list(self.facts)}")


def check_plan(n: int, noise: float, noisy_fraction: float) -> None:
    """Refuse a plan's counts, naming the bad value."""
    if n < 1:
        raise ValueError(f"episodes must be >= 1, got {n}")
    if noise < 0 or not 0 <= noisy_fraction <= 1:
        raise ValueError(f"noise must be >= 0 and noisy_fraction in [0, 1], got {noise}, {noisy_fraction}")


def plan_episodes(n: int, seed: int = 0, noise: float = 0.0, noisy_fraction: float = 0.5,
                  mix: PromptMix | None = None) -> list[DemoEpisode]:
    """``n`` episodes at env seeds ``seed..seed+n-1``, prompt kinds drawn by ``mix``, ``noisy_fraction`` of them with
    arm noise ``noise``; each episode's env draws its own group (a cue's colour)."""
    check_plan(n, noise, noisy_fraction)
    mix = mix or PromptMix()
    rng = np.random.default_rng(seed)
    kinds = rng.choice(len(PROMPT_KINDS), size=n, p=mix.weights)
    noisy = rng.random(n) < noisy_fraction
    return [DemoEpisode(seed + k, PROMPT_KINDS[kinds[k]], noise if noisy[k] else 0.0) for k in range(n)]


__all__ = ["DemoEpisode", "PROMPT_KINDS", "PromptMix", "check_plan", "plan_episodes"]
