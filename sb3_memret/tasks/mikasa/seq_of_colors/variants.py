"""MIKASA-Robo-VLA's colour-cue tasks, by id: BunchOfColors, SeqOfColors and ChainOfColors, 3, 5 or 7 of the nine
colours, in their 400-step form and their -Long one (MIKASA's ``register_env`` lengths).

- **SeqOfColors** shows the cue colours one at a time at the table centre; its instruction says "in any order", but
  MIKASA's success checks the order (``wrong_order_touched``: the k-th distinct cube touched must be the k-th item).
- **ChainOfColors** shows them the same way and its instruction and success both ask for the cue's order.
- **BunchOfColors** shows them together, on an arc round the table centre; the order of touching is free.

Each item of a sequence shows 1-5 steps (-Long: 10-100), a bunch 1-5 steps in all (-Long: 10-100), then the table is
empty for 1-5 steps (-Long: 50-400) before all nine cubes come back.
"""

from __future__ import annotations

from dataclasses import dataclass

SHOWN_ONE_BY_ONE, SHOWN_TOGETHER = "one by one", "together"
ANY_ORDER = ("observe which colored cubes appear during the cue, wait, then touch all of them in any order "
             "and press the center button.")
CUE_ORDER = ("observe which colored cubes appear during the cue, wait, then touch all of them in the same order "
             "as the cubes were shown and press the center button.")


@dataclass(frozen=True)
class ColourCueVariant:
    """One of MIKASA's colour-cue tasks: how its cue is shown, how many colours, its episode length and its
    instruction (MIKASA's ``LANGUAGE_INSTRUCTION``, lowercased for the prompt contract)."""

    env_id: str
    shown: str  # SHOWN_ONE_BY_ONE or SHOWN_TOGETHER
    n_items: int
    episode_steps: int
    instruction: str

    @property
    def together(self) -> bool:
        return self.shown == SHOWN_TOGETHER


def _variants() -> dict[str, ColourCueVariant]:
    out = {}
    for family, shown, instruction, long_steps in (
            ("BunchOfColors", SHOWN_TOGETHER, ANY_ORDER, {3: 700, 5: 700, 7: 700}),
            ("SeqOfColors", SHOWN_ONE_BY_ONE, ANY_ORDER, {3: 800, 5: 1000, 7: 1200}),
            ("ChainOfColors", SHOWN_ONE_BY_ONE, CUE_ORDER, {3: 800, 5: 1000, 7: 1200})):
        for n in (3, 5, 7):
            for suffix, steps in (("", 400), ("-Long", long_steps[n])):
                env_id = f"{family}{n}{suffix}-VLA-v0"
                out[env_id] = ColourCueVariant(env_id, shown, n, steps, instruction)
    return out


VARIANTS: dict[str, ColourCueVariant] = _variants()


def variant(env_id: str) -> ColourCueVariant:
    """The variant ``env_id`` names; else a ValueError listing the ids."""
    if env_id not in VARIANTS:
        raise ValueError(f"unknown colour-cue task {env_id!r}; expected one of {sorted(VARIANTS)}")
    return VARIANTS[env_id]


__all__ = ["ANY_ORDER", "CUE_ORDER", "ColourCueVariant", "SHOWN_ONE_BY_ONE", "SHOWN_TOGETHER", "VARIANTS", "variant"]
