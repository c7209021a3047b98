"""Households: objects stay in their drawers across tasks until the household rearranges them."""

import numpy as np
import pytest

from sb3_memret.tasks.drawer.cabinet import LAYERS
from sb3_memret.tasks.drawer.household import Household, HouseholdConfig
from sb3_memret.tasks.drawer.objects import OBJECT_SETS

OBJECTS = OBJECT_SETS["train"]


def test_the_placement_stays_until_a_move_and_the_target_is_always_placed():
    household, rng = Household(OBJECTS, 3, HouseholdConfig(move_probability=0.0)), np.random.default_rng(0)
    first, target, moved = household.next_episode(rng)
    assert moved and len(first) == 3 and sorted(first.values()) == list(LAYERS) and target in first
    targets = set()
    for _ in range(20):
        placement, target, moved = household.next_episode(rng)
        assert placement == first and not moved and target in placement
        targets.add(target)
    assert targets == set(first) and household.episodes_since_move == 21


def test_moves_happen_at_the_configured_rate():
    household, rng = Household(OBJECTS, 3, HouseholdConfig(move_probability=0.3)), np.random.default_rng(1)
    household.next_episode(rng)
    moves = [household.next_episode(rng)[2] for _ in range(400)]
    assert 0.24 < np.mean(moves) < 0.36


@pytest.mark.parametrize("config,message", [
    (dict(move_probability=1.5), r"move_probability must be in \[0, 1\]"),
    (dict(hearsay_per_episode=-1), "hearsay_per_episode must be >= 0"),
    (dict(glimpses_per_episode=4), r"glimpses_per_episode must be in \[0, 3\]"),
])
def test_bad_settings_are_refused(config, message):
    with pytest.raises(ValueError, match=message):
        HouseholdConfig(**config)


def test_more_objects_than_drawers_is_refused():
    with pytest.raises(ValueError, match=r"n_objects in \[1, 3\]"):
        Household(OBJECTS, 4, HouseholdConfig())
