"""Property tests of the bounded bank."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sb3_memret.memory.bank import MemoryBank, importance_scorer
from sb3_memret.memory.schema import MemoryEntry, MemoryType

OBJECTS = ["cube", "key", "mug", "fork", "pen", "ball", "cup", "box"]


def entry(obj: str, layer: int, t: int = 0, mtype=MemoryType.OBJECT_LOCATION) -> MemoryEntry:
    e = MemoryEntry.create(mtype, obj, "is_in", f"drawer layer {layer}", t)
    rng = np.random.default_rng(abs(hash(e.text)) % 2**32)
    return e.with_embedding(rng.standard_normal(384).astype(np.float32))


def value_scorer(values: dict):
    """Keep-score = a fixed value per object (ties broken by position, as argmin does)."""
    return lambda entries: np.array([values[e.entity] for e in entries])


writes = st.lists(st.tuples(st.sampled_from(OBJECTS), st.integers(1, 3)), max_size=40)
values = st.fixed_dictionaries({o: st.floats(-10, 10, allow_nan=False) for o in OBJECTS})


@settings(max_examples=150, deadline=None)
@given(capacity=st.integers(1, 6), ops=writes, vals=values)
def test_bank_invariants(capacity, ops, vals):
    bank = MemoryBank(capacity)
    scorer = value_scorer(vals)
    for t, (obj, layer) in enumerate(ops):
        before = bank.entries
        new = entry(obj, layer, t)
        outcome = bank.write(new, scorer)
        after = bank.entries
        # never over capacity, keys unique
        assert len(after) <= capacity
        assert len({e.key for e in after}) == len(after)
        same_key = [i for i, e in enumerate(before) if e.key == new.key]
        if same_key:
            # in-place replacement: same slot, others untouched
            assert outcome.replaced and outcome.slot == same_key[0]
            assert after[same_key[0]] is new
            assert [e for i, e in enumerate(after) if i != same_key[0]] == [e for i, e in enumerate(before) if i != same_key[0]]
        elif len(before) < capacity:
            assert after == [*before, new]
        else:
            # eviction is the argmin of the scorer over stored entries and the newcomer
            scores = scorer([*before, new])
            loser = int(np.argmin(scores))
            if loser == capacity:
                assert outcome.slot is None and after == before
            else:
                assert outcome.evicted is before[loser] and after[loser] is new
        view = bank.view()
        assert view.mask.sum() == len(after) and view.mask[: len(after)].all()
        for i, e in enumerate(after):
            np.testing.assert_array_equal(view.embeddings[i], e.embedding)
            assert view.type_ids[i] == int(e.type)
        assert not view.embeddings[len(after):].any()


def test_usage_and_age_tracking():
    bank = MemoryBank(3)
    bank.write(entry("cube", 2, t=4))
    bank.write(entry("key", 1, t=10))
    bank.mark_used(0)
    bank.mark_used(0)
    bank.age(16)
    view = bank.view()
    np.testing.assert_array_equal(view.usage, [2, 0, 0])
    np.testing.assert_array_equal(view.age, [12, 6, 0])
    with pytest.raises(IndexError, match="slot 2 is empty"):
        bank.mark_used(2)


def test_default_scorer_is_the_type_prior():
    bank = MemoryBank(1)
    holding = MemoryEntry.create(MemoryType.HOLDING, "robot", "holding", "key", 0).with_embedding(np.zeros(384))
    bank.write(holding)
    outcome = bank.write(entry("cube", 1), importance_scorer)
    assert outcome.evicted is holding and bank.entries[0].entity == "cube"


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="capacity must be a positive int"):
        MemoryBank(0)
    bank = MemoryBank(2)
    with pytest.raises(ValueError, match="encode entries before writing"):
        bank.write(MemoryEntry.create(MemoryType.OBJECT_LOCATION, "cube", "is_in", "drawer layer 1", 0))
    bank.write(entry("cube", 1))
    bank.write(entry("key", 1))
    with pytest.raises(ValueError, match=r"keep_scorer returned shape \(2,\), expected \(3,\)"):
        bank.write(entry("mug", 1), lambda entries: np.zeros(2))
