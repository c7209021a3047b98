"""A household: which objects live in which drawers, kept from one episode to the next and sometimes moved.

The long-term memory variant plays its episodes in one household per env. Objects stay in their
drawers across episodes (an object the robot took out is put back where it was), so a fact
seen in an earlier episode can help in a later one; now and then the household rearranges the
drawers, and what was remembered becomes stale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sb3_memret.tasks.drawer.cabinet import LAYERS


@dataclass(frozen=True)
class HouseholdConfig:
    """How a household lives: the chance, per episode, that it rearranges the drawers; how many
    location facts about other things (hearsay: right or wrong, never about its objects) reach the
    long-term store per episode; and how many drawers, drawn at random, the robot looks into before
    each episode (a glimpse: what it sees there is written, the rest it must remember)."""

    move_probability: float = 0.2
    hearsay_per_episode: int = 2
    glimpses_per_episode: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.move_probability <= 1.0:
            raise ValueError(f"move_probability must be in [0, 1], got {self.move_probability}")
        if self.hearsay_per_episode < 0:
            raise ValueError(f"hearsay_per_episode must be >= 0, got {self.hearsay_per_episode}")
        if not 0 <= self.glimpses_per_episode <= len(LAYERS):
            raise ValueError(f"glimpses_per_episode must be in [0, {len(LAYERS)}] (drawers looked into), "
                             f"got {self.glimpses_per_episode}")


class Household:
    """One env's drawers: ``n_objects`` of ``objects``, one per drawer, and each episode's target.

    ``next_episode`` keeps the arrangement, or with ``move_probability`` draws a new one (other
    objects, other drawers), then picks the target uniformly among the placed objects.
    ``episodes_since_move`` counts the episodes played in the current arrangement.
    """

    def __init__(self, objects: tuple[str, ...], n_objects: int, config: HouseholdConfig):
        if not 1 <= n_objects <= min(len(objects), len(LAYERS)):
            raise ValueError(f"a household puts n_objects in [1, {min(len(objects), len(LAYERS))}] of {list(objects)} "
                             f"in its {len(LAYERS)} drawers, got {n_objects}")
        self.objects, self.n_objects, self.config = tuple(objects), n_objects, config
        self.placement: dict[str, int] = {}
        self.episodes_since_move = 0

    def next_episode(self, rng: np.random.Generator) -> tuple[dict[str, int], str, bool]:
        """The next episode's placement (name -> layer), its target, and whether the drawers were rearranged."""
        moved = not self.placement or rng.random() < self.config.move_probability
        if moved:
            names = rng.choice(len(self.objects), size=self.n_objects, replace=False)
            layers = rng.permutation(LAYERS)[: self.n_objects]
            self.placement = {self.objects[i]: int(layer) for i, layer in zip(names, layers)}
            self.episodes_since_move = 0
        self.episodes_since_move += 1
        target = str(rng.choice(sorted(self.placement)))
        return dict(self.placement), target, moved


__all__ = ["Household", "HouseholdConfig"]
