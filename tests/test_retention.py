"""Fixed eviction rules on a real bank: which entry each one lets go."""

import numpy as np
import pytest

from sb3_memret.memory.bank import MemoryBank
from sb3_memret.memory.retention import check_retention, fifo_scores, lru_scores, prior_scores
from sb3_memret.memory.schema import MemoryEntry, MemoryType


def fact(entity: str, t: int, mtype: MemoryType = MemoryType.OBJECT_LOCATION) -> MemoryEntry:
    if mtype == MemoryType.HOLDING:
        entry = MemoryEntry.create(mtype, "robot", "holding", entity, t)
    else:
        entry = MemoryEntry.create(mtype, entity, "is_in", "drawer layer 1", t)
    return entry.with_embedding(np.ones(384, dtype=np.float32))


def full_bank(*entries: MemoryEntry) -> MemoryBank:
    bank = MemoryBank(len(entries))
    for entry in entries:
        bank.write(entry)
    return bank


def test_fifo_lets_the_oldest_go():
    bank = full_bank(fact("tin", 5), fact("key", 1), fact("mug", 3))
    outcome = bank.write(fact("box", 9), fifo_scores)
    assert outcome.evicted.entity == "key" and [e.entity for e in bank.entries] == ["tin", "box", "mug"]


def test_lru_keeps_an_old_fact_that_was_retrieved_lately():
    bank = full_bank(fact("tin", 5), fact("key", 1), fact("mug", 3))
    bank.mark_used(1, now=8)
    outcome = bank.write(fact("box", 9), lru_scores)
    assert outcome.evicted.entity == "mug"
    assert bank.entries[1].usage_count == 1 and bank.entries[1].last_used == 8


def test_prior_ranks_by_type_and_the_newcomer_can_lose():
    bank = full_bank(fact("tin", 5), fact("key", 1))
    outcome = bank.write(fact("marker", 9, MemoryType.HOLDING), prior_scores)
    assert outcome.slot is None and outcome.evicted.text == "the robot is holding the marker."


def test_unknown_rule_is_refused():
    assert check_retention("lru") == "lru"
    with pytest.raises(ValueError, match=r"unknown retention rule 'random'; expected one of \['learned', 'fifo'"):
        check_retention("random")
