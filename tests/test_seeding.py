import numpy as np
import pytest

from sb3_memret.memory.schema import MemoryType
from sb3_memret.tasks.drawer.objects import CATALOGUE
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.tasks.drawer.seeding import is_true_memory, seed_memories
from sb3_memret.controllers.prompts import build_prompt, parse_prompt
from sb3_memret.tasks.drawer.prompts import ANY_OBJECT, INSTRUCTION, TEMPLATE, instruction_text, named_layer


@pytest.mark.parametrize("layer", [1, 2, 3])
def test_one_true_memory_among_decoys_on_other_layers(layer):
    for seed in range(20):
        entries = seed_memories({"cube": layer}, "cube", np.random.default_rng(seed))
        assert len(entries) == 8
        true = [e for e in entries if is_true_memory(e, "cube", layer)]
        assert len(true) == 1
        locations = [e for e in entries if e.type == MemoryType.OBJECT_LOCATION and e is not true[0]]
        holdings = [e for e in entries if e.type == MemoryType.HOLDING]
        assert len(locations) == 5 and len(holdings) == 2
        assert len({e.entity for e in locations}) == 5 and "cube" not in {e.entity for e in locations}
        for e in entries:
            fact_layer = named_layer(parse_prompt(build_prompt(INSTRUCTION, [e.text], TEMPLATE), TEMPLATE))
            assert (fact_layer == layer) == (e is true[0])


def test_seeding_is_reproducible_and_shuffled():
    a = [e.text for e in seed_memories({"cube": 2}, "cube", np.random.default_rng(3))]
    b = [e.text for e in seed_memories({"cube": 2}, "cube", np.random.default_rng(3))]
    assert a == b
    positions = {[e.text for e in seed_memories({"cube": 2}, "cube", np.random.default_rng(s))].index("the cube is in drawer layer 2.") for s in range(30)}
    assert len(positions) > 3


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="must not contain task objects"):
        SeedingConfig(vocabulary=("cube", "key", "mug", "fork", "pen")).check_task_objects(CATALOGUE)
    with pytest.raises(ValueError, match="must not contain task objects"):  # the drawer checks what it seeds with
        seed_memories({"cube": 1}, "cube", np.random.default_rng(0), SeedingConfig(vocabulary=("cube", "key", "mug",
                                                                                               "fork", "pen")))
    with pytest.raises(ValueError, match="need at least 5 distinct decoy objects"):
        SeedingConfig(vocabulary=("key", "mug"))


def test_several_objects_each_placed_where_they_are_and_only_the_target_is_true():
    placed = {"brick": 3, "cube": 1, "tin": 2}
    for seed in range(20):
        entries = seed_memories(placed, "tin", np.random.default_rng(seed), SeedingConfig(location_decoys=1))
        assert len(entries) == 3 + 1 + 2
        facts = {e.entity: e.value for e in entries if e.type == MemoryType.OBJECT_LOCATION}
        assert {name: facts[name] for name in placed} == {name: f"drawer layer {layer}" for name, layer in placed.items()}
        assert [e.text for e in entries if is_true_memory(e, "tin", 2)] == ["the tin is in drawer layer 2."]
        decoy, = set(facts) - set(placed)
        assert facts[decoy] != "drawer layer 2"  # a decoy never points at the target's drawer
        for e in entries:  # every memory is a sentence a controller trained on several objects accepts
            build_prompt(instruction_text("tin"), [e.text], ANY_OBJECT)


def test_the_target_must_be_placed():
    with pytest.raises(ValueError, match="target 'dice' is not among the placed objects"):
        seed_memories({"cube": 1}, "dice", np.random.default_rng(0))
