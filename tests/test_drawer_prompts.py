import pytest

from sb3_memret.controllers.prompts import build_prompt, parse_prompt
from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer.prompts import (ANY_OBJECT, HOLDING_TEMPLATE, INSTRUCTION, LAYER_LOCATION_TEMPLATE,
                                             TEMPLATE, check_prompt_layer, condition_prompt, holding_text,
                                             instruction_text, location_text, named_layer)


def test_round_trip_of_the_drawers_instruction_and_memories():
    prompt = build_prompt(INSTRUCTION, [location_text("cube", 2), holding_text("marker")], TEMPLATE)
    assert prompt == "pick out the cube. the cube is in drawer layer 2. the robot is holding the marker."
    parsed = parse_prompt(prompt, TEMPLATE)
    assert parsed.instruction == INSTRUCTION
    assert [f.template for f in parsed.facts] == [LAYER_LOCATION_TEMPLATE, HOLDING_TEMPLATE]
    assert dict(parsed.facts[0].fields) == {"entity": "cube", "layer": "2"}
    assert named_layer(parsed) == 2 and DrawerTask().prompt_template == TEMPLATE


def test_special_texts_are_part_of_the_drawers_contract():
    prompt = build_prompt(INSTRUCTION, [holding_text("nothing"), "the cube is out of the drawers."], TEMPLATE)
    assert prompt == "pick out the cube. the robot is holding nothing. the cube is out of the drawers."
    assert named_layer(parse_prompt(prompt, TEMPLATE)) is None


def test_the_layer_follows_the_first_location_fact_whatever_the_object():
    assert named_layer(parse_prompt("pick out the cube. the key is in drawer layer 3.", TEMPLATE)) == 3
    assert named_layer(parse_prompt("pick out the cube. the robot is holding the key.", TEMPLATE)) is None
    with pytest.raises(ValueError, match="matches no trained template"):
        parse_prompt("pick out the cube. the cube is in drawer layer two.", TEMPLATE)  # a layer is a number


def test_the_seeds_contract_takes_the_cube_alone_and_any_object_takes_any_word():
    parsed = parse_prompt("pick out the tin. the tin is in drawer layer 3.", ANY_OBJECT)
    assert dict(parsed.instruction_fields) == {"entity": "tin"} and named_layer(parsed) == 3
    with pytest.raises(ValueError, match="starts with 'pick out the tin.'"):
        parse_prompt("pick out the tin.", TEMPLATE)
    with pytest.raises(ValueError, match="starts with 'pick up the tin.'"):
        parse_prompt("pick up the tin.", ANY_OBJECT)
    assert instruction_text("soap") == "pick out the soap."


def test_condition_prompts():
    assert condition_prompt("oracle", 3) == "pick out the cube. the cube is in drawer layer 3."
    assert condition_prompt("none", 2) == INSTRUCTION
    for layer in (1, 2, 3):
        wrong = named_layer(parse_prompt(condition_prompt("wrong", layer), TEMPLATE))
        assert wrong is not None and wrong != layer
    with pytest.raises(ValueError, match="unknown condition 'maybe'"):
        condition_prompt("maybe", 1)
    with pytest.raises(ValueError, match="drawer layer must be one of"):
        condition_prompt("oracle", 0)


def test_condition_prompts_name_any_target():
    assert condition_prompt("wrong", 3, "dice") == "pick out the dice. the dice is in drawer layer 1."
    assert location_text("tin", 2) == "the tin is in drawer layer 2."


def test_a_layer_the_cabinet_lacks_is_refused_by_the_drawer_not_by_the_prompt_contract():
    parsed = parse_prompt("pick out the cube. the cube is in drawer layer 4.", TEMPLATE)  # any number parses
    assert named_layer(parsed) == 4
    with pytest.raises(ValueError, match="names drawer layer 4; the cabinet's layers are \\[1, 2, 3\\]"):
        DrawerTask().check_prompt(parsed)
    with pytest.raises(ValueError, match="drawer layer 4"):
        check_prompt_layer(parsed)
    assert check_prompt_layer(parse_prompt("pick out the cube. the cube is in drawer layer 3.", TEMPLATE)) == 3
    assert check_prompt_layer(parse_prompt(INSTRUCTION, TEMPLATE)) is None
