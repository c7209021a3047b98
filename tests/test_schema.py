import pytest

from sb3_memret.memory.schema import IMPORTANCE, TEMPLATES, MemoryEntry, MemoryType, linearize
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks.drawer.prompts import INSTRUCTION, TEMPLATE
from sb3_memret.tasks.drawer import DrawerTask


def test_six_types_each_with_template_and_importance():
    assert len(MemoryType) == 6
    assert set(TEMPLATES) == set(MemoryType) == set(IMPORTANCE)
    for template in TEMPLATES.values():
        assert template == template.lower() and template.endswith(".")


def test_texts_are_exactly_the_controller_prompts():
    cube = MemoryEntry.create(MemoryType.OBJECT_LOCATION, "cube", "is_in", "drawer layer 2", timestamp=30)
    assert cube.text == "the cube is in drawer layer 2."
    assert cube.key == (MemoryType.OBJECT_LOCATION, "cube", "is_in")
    assert cube.importance == IMPORTANCE[MemoryType.OBJECT_LOCATION] and cube.usage_count == 0
    holding = MemoryEntry.create(MemoryType.HOLDING, "robot", "holding", "cube", timestamp=3)
    assert holding.text == "the robot is holding the cube."
    assert MemoryEntry.create(MemoryType.HOLDING, "robot", "holding", "nothing", 0).text == "the robot is holding nothing."
    out = MemoryEntry.create(MemoryType.OBJECT_LOCATION, "cube", "is_in", "outside", 0, wordings=DrawerTask.wordings)
    assert out.text == "the cube is out of the drawers."
    # everything the writer emits for this task passes the scripted controller's prompt contract
    build_prompt(INSTRUCTION, [cube.text, holding.text, out.text], TEMPLATE)


def test_other_types_have_readable_templates():
    assert linearize(MemoryType.FAILURE, "cube", "grasp", "true") == "the robot failed to grasp the cube."
    assert linearize(MemoryType.COUNT, "cube", "count", "2") == "there are 2 cube objects."
    assert linearize(MemoryType.TASK_PROGRESS, "drawer", "state", "open") == "the drawer is open."


@pytest.mark.parametrize("bad", ["Cube", " cube", "cube.", ""])
def test_fields_must_be_lowercase_words(bad):
    with pytest.raises(ValueError, match="lowercase"):
        linearize(MemoryType.OBJECT_LOCATION, bad, "is_in", "drawer layer 1")


def test_a_task_words_its_own_values_and_the_schema_knows_no_task():
    generic = linearize(MemoryType.OBJECT_LOCATION, "cube", "is_in", "outside")
    assert generic == "the cube is in outside."  # the schema's template: no drawer wording in memory/
    drawer = linearize(MemoryType.OBJECT_LOCATION, "cube", "is_in", "outside", DrawerTask.wordings)
    assert drawer == "the cube is out of the drawers."
    entry = MemoryEntry.create(MemoryType.OBJECT_LOCATION, "cube", "is_in", "outside", 3, wordings=DrawerTask.wordings)
    assert entry.text == drawer
    assert linearize(MemoryType.HOLDING, "robot", "holding", "nothing") == "the robot is holding nothing."
