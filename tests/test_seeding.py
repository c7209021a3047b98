import numpy as np
import pytest

from sb3_memret.memory.schema import MemoryType
from sb3_memret.memory.seeding import SeedingConfig, is_true_cube_memory, seed_memories
from sb3_memret.prompts import INSTRUCTION, build_prompt, parse_prompt


@pytest.mark.parametrize("layer", [1, 2, 3])
def test_one_true_memory_among_decoys_on_other_layers(layer):
    for seed in range(20):
        entries = seed_memories(layer, np.random.default_rng(seed))
        assert len(entries) == 8
        true = [e for e in entries if is_true_cube_memory(e, layer)]
        assert len(true) == 1
        locations = [e for e in entries if e.type == MemoryType.OBJECT_LOCATION and e is not true[0]]
        holdings = [e for e in entries if e.type == MemoryType.HOLDING]
        assert len(locations) == 5 and len(holdings) == 2
        assert len({e.entity for e in locations}) == 5 and "cube" not in {e.entity for e in locations}
        for e in entries:
            fact_layer = parse_prompt(build_prompt(INSTRUCTION, [e.text])).layer
            assert (fact_layer == layer) == (e is true[0])


def test_seeding_is_reproducible_and_shuffled():
    a = [e.text for e in seed_memories(2, np.random.default_rng(3))]
    b = [e.text for e in seed_memories(2, np.random.default_rng(3))]
    assert a == b
    positions = {[e.text for e in seed_memories(2, np.random.default_rng(s))].index("the cube is in drawer layer 2.") for s in range(30)}
    assert len(positions) > 3


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="must not contain 'cube'"):
        SeedingConfig(vocabulary=("cube", "key", "mug", "fork", "pen"))
    with pytest.raises(ValueError, match="need at least 5 distinct decoy objects"):
        SeedingConfig(vocabulary=("key", "mug"))
