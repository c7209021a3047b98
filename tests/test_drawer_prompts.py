import pytest

from sb3_memret.controllers.prompts import INSTRUCTION, parse_prompt
from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer.prompts import check_prompt_layer, condition_prompt, location_text


def test_condition_prompts():
    assert condition_prompt("oracle", 3) == "pick out the cube. the cube is in drawer layer 3."
    assert condition_prompt("none", 2) == INSTRUCTION
    for layer in (1, 2, 3):
        wrong = parse_prompt(condition_prompt("wrong", layer)).layer
        assert wrong is not None and wrong != layer
    with pytest.raises(ValueError, match="unknown condition 'maybe'"):
        condition_prompt("maybe", 1)
    with pytest.raises(ValueError, match="drawer layer must be one of"):
        condition_prompt("oracle", 0)


def test_condition_prompts_name_any_target():
    assert condition_prompt("wrong", 3, "dice") == "pick out the dice. the dice is in drawer layer 1."
    assert location_text("tin", 2) == "the tin is in drawer layer 2."


def test_a_layer_the_cabinet_lacks_is_refused_by_the_drawer_not_by_the_prompt_contract():
    parsed = parse_prompt("pick out the cube. the cube is in drawer layer 4.")  # the contract takes any number
    assert parsed.layer == 4
    with pytest.raises(ValueError, match="names drawer layer 4; the cabinet's layers are \\[1, 2, 3\\]"):
        DrawerTask().check_prompt(parsed)
    with pytest.raises(ValueError, match="drawer layer 4"):
        check_prompt_layer(parsed)
    assert check_prompt_layer(parse_prompt("pick out the cube. the cube is in drawer layer 3.")) == 3
    assert check_prompt_layer(parse_prompt(INSTRUCTION)) is None
