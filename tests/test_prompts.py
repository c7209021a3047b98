import pytest

from sb3_memret.controllers.prompts import (HOLDING_TEMPLATE, INSTRUCTION, INSTRUCTION_TEMPLATE, LAYER_LOCATION_TEMPLATE,
                                PromptTemplate, build_prompt, holding_text, instruction_text, parse_prompt)
from sb3_memret.tasks.drawer.prompts import location_text


def test_round_trip_of_instruction_and_memories():
    prompt = build_prompt(INSTRUCTION, [location_text("cube", 2), holding_text("marker")])
    assert prompt == "pick out the cube. the cube is in drawer layer 2. the robot is holding the marker."
    parsed = parse_prompt(prompt)
    assert parsed.instruction == INSTRUCTION
    assert [f.template for f in parsed.facts] == [LAYER_LOCATION_TEMPLATE, HOLDING_TEMPLATE]
    assert dict(parsed.facts[0].fields) == {"entity": "cube", "layer": "2"}
    assert dict(parsed.facts[1].fields) == {"value": "marker"}
    assert parsed.layer == 2


def test_special_texts_are_part_of_the_contract():
    prompt = build_prompt(INSTRUCTION, [holding_text("nothing"), "the cube is out of the drawers."])
    assert prompt == "pick out the cube. the robot is holding nothing. the cube is out of the drawers."
    assert parse_prompt(prompt).layer is None


def test_layer_follows_first_location_fact_whatever_the_object():
    assert parse_prompt("pick out the cube. the key is in drawer layer 3.").layer == 3
    assert parse_prompt("pick out the cube. the robot is holding the key.").layer is None
    assert parse_prompt(INSTRUCTION).layer is None


@pytest.mark.parametrize(
    "prompt",
    [
        "pick out the cube. The cube is in drawer layer 2.",  # capitalised
        "pick out the cube.  the cube is in drawer layer 2.",  # double space
        "pick out the cube. the cube is in drawer layer 2",  # no full stop
        "pick out the cube. the cube is in drawer 2.",  # wording drift
        " pick out the cube.",  # leading space
        "grab the cube.",  # unknown instruction
        "",
    ],
)
def test_drifted_prompts_are_refused_with_the_offending_text(prompt):
    with pytest.raises(ValueError) as err:
        parse_prompt(prompt)
    assert repr(prompt) in str(err.value) or repr(prompt.strip()) in str(err.value) or "malformed" in str(err.value)


def test_template_restricts_accepted_facts():
    only_locations = PromptTemplate(fact_templates=(LAYER_LOCATION_TEMPLATE,))
    with pytest.raises(ValueError, match="no trained template"):
        parse_prompt("pick out the cube. the robot is holding the key.", only_locations)


def test_instruction_templates_take_any_object_word_and_name_the_target():
    general = PromptTemplate((INSTRUCTION_TEMPLATE,))
    parsed = parse_prompt("pick out the tin. the tin is in drawer layer 3.", general)
    assert parsed.target == "tin" and parsed.layer == 3
    assert parse_prompt("pick out the cube.").target == "cube"
    with pytest.raises(ValueError, match="starts with 'pick out the tin.'"):
        parse_prompt("pick out the tin.")  # the seed's contract: the cube alone
    with pytest.raises(ValueError, match="starts with 'pick up the tin.'"):
        parse_prompt("pick up the tin.", general)
    assert instruction_text("soap") == "pick out the soap."
