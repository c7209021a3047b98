"""Which demonstrations to record: each episode's seed, prompt kind, arm noise and reset options.

A plan is the task's (``Task.plan_demos``): by default each episode's prompt kind is drawn by ``PromptMix`` (the bare
instruction, the task's true facts, facts naming something else, or the facts as a recall memory gives them: a decoy
until the writer has read the true ones) and the recorder words the facts from the episode's ground truth. A task
that chooses its episodes' groups itself (the drawer: the target's layer, cycled) sets ``reset_options``, and may name
the facts outright (``DemoEpisode.facts``). Recording is ``sb3_memret.stage1.demos``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

PROMPT_KINDS = ("bare", "matching", "mismatched", "recalled")


@dataclass(frozen=True)
class PromptMix:
    """How episodes' prompts are drawn: bare, the true facts, facts naming something else, and ``recalled``: what
    the recall condition's memory puts in the prompt, a decoy about another thing until the task's writer has read the
    true facts, then those (a controller trained on it learns to wait out a fact that is not yet known)."""

    bare: float = 0.2
    matching: float = 0.6
    mismatched: float = 0.2
    recalled: float = 0.0

    def __post_init__(self) -> None:
        weights = self.weights
        if min(weights) < 0 or not np.isclose(sum(weights), 1.0):
            raise ValueError(f"prompt mix {dict(zip(PROMPT_KINDS, weights))} must be non-negative and sum to 1")

    @property
    def weights(self) -> list[float]:
        """The probabilities of ``PROMPT_KINDS``, in order."""
        return [self.bare, self.matching, self.mismatched, self.recalled]

    @classmethod
    def parse(cls, text: str) -> "PromptMix":
        """A mix from ``kind=share`` pairs, comma-separated (``bare=0.2,matching=0.5,mismatched=0.15,recalled=0.15``);
        a kind left out has share 0."""
        shares: dict[str, float] = {}
        for part in (p.strip() for p in text.split(",") if p.strip()):
            kind, sep, value = part.partition("=")
            if not sep or kind.strip() not in PROMPT_KINDS:
                raise ValueError(f"bad prompt mix entry {part!r}: expected KIND=SHARE with KIND one of "
                                 f"{list(PROMPT_KINDS)}")
            try:
                shares[kind.strip()] = float(value)
            except ValueError:
                raise ValueError(f"bad prompt mix share {value!r} for {kind.strip()!r}: expected a number") from None
        return cls(**{kind: shares.get(kind, 0.0) for kind in PROMPT_KINDS})


@dataclass(frozen=True)
class DemoEpisode:
    """One demonstration to record: the env seed, which prompt it gets, the action noise on the arm, the reset
    options that choose its group (none: the env draws it), and the facts its prompt carries when the plan names
    them (None: the task's true facts for ``matching``, its wrong ones for ``mismatched``, none for ``bare``, a decoy
    then the true facts once written for ``recalled``)."""

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
        if self.prompt_kind == "recalled" and self.facts is not None:
            raise ValueError(f"a recalled prompt's facts follow what the writer reads; a plan cannot name them, "
                             f"got {list(self.facts)}")


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
