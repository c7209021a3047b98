"""The prompt contract, on a template of its own: sentences checked byte for byte, fields parsed by their patterns,
drift refused naming the offending text."""

import pytest

from sb3_memret.controllers.prompts import NUMBER, SIGNED_NUMBER, WORDS, PromptTemplate, build_prompt, parse_prompt

INSTRUCTION = "open the {colour} door."
KEY_FACT = "the key is behind door {door}."
TURN_FACT = "the handle turns {angle} degrees."
HELD = "the robot is holding nothing."
DOORS = PromptTemplate((INSTRUCTION,), (KEY_FACT, TURN_FACT, HELD), (("door", NUMBER), ("angle", SIGNED_NUMBER)))


def test_round_trip_of_instruction_and_facts():
    prompt = build_prompt("open the red door.", ["the key is behind door 2.", HELD], DOORS)
    assert prompt == "open the red door. the key is behind door 2. the robot is holding nothing."
    parsed = parse_prompt(prompt, DOORS)
    assert parsed.instruction == "open the red door." and dict(parsed.instruction_fields) == {"colour": "red"}
    assert [f.template for f in parsed.facts] == [KEY_FACT, HELD]
    assert dict(parsed.facts[0].fields) == {"door": "2"} and parsed.facts[1].fields == ()
    assert parsed.field("door") == "2" and parsed.facts[0].value("door") == "2" and parsed.field("angle") is None


def test_each_field_holds_what_its_pattern_says():
    assert parse_prompt("open the dark red door. the handle turns -90 degrees.", DOORS).field("angle") == "-90"
    assert dict(parse_prompt("open the dark red door.", DOORS).instruction_fields) == {"colour": "dark red"}
    with pytest.raises(ValueError, match="matches no trained template"):
        parse_prompt("open the red door. the key is behind door -2.", DOORS)  # a door is unsigned
    with pytest.raises(ValueError, match="matches no trained template"):
        parse_prompt("open the red door. the key is behind door two.", DOORS)  # a number field takes no words
    words = PromptTemplate((INSTRUCTION,), (KEY_FACT,))  # without patterns every field holds words
    assert parse_prompt("open the red door. the key is behind door two.", words).field("door") == "two"


def test_the_first_fact_with_a_field_names_it():
    parsed = parse_prompt("open the red door. the robot is holding nothing. the key is behind door 3. "
                          "the key is behind door 1.", DOORS)
    assert parsed.field("door") == "3"


@pytest.mark.parametrize(
    "prompt",
    [
        "open the red door. The key is behind door 2.",  # capitalised
        "open the red door.  the key is behind door 2.",  # double space
        "open the red door. the key is behind door 2",  # no full stop
        "open the red door. the key" + " is behind door 2" * 5000,  # a long tail without one (refused before the scan)
        "open the red door. the key is behind the door 2.",  # wording drift
        " open the red door.",  # leading space
        "push the red door.",  # unknown instruction
        "",
    ],
)
def test_drifted_prompts_are_refused_with_the_offending_text(prompt):
    with pytest.raises(ValueError) as err:
        parse_prompt(prompt, DOORS)
    assert repr(prompt) in str(err.value) or repr(prompt.strip()) in str(err.value) or "malformed" in str(err.value)


def test_template_restricts_accepted_facts_and_instructions():
    only_keys = PromptTemplate((INSTRUCTION,), (KEY_FACT,), DOORS.fields)
    with pytest.raises(ValueError, match="no trained template"):
        parse_prompt("open the red door. the robot is holding nothing.", only_keys)
    literal = PromptTemplate(("open the red door.",), (KEY_FACT,))
    with pytest.raises(ValueError, match="starts with 'open the blue door.'"):
        parse_prompt("open the blue door.", literal)
    with pytest.raises(TypeError, match="prompt must be a str"):
        parse_prompt(3, DOORS)


def test_a_template_without_instructions_or_with_a_bad_pattern_is_refused():
    with pytest.raises(ValueError, match="needs a tuple of instructions"):
        PromptTemplate((), (KEY_FACT,))
    with pytest.raises(ValueError, match="needs a tuple of instructions"):
        PromptTemplate("open the red door.")
    with pytest.raises(Exception, match="unterminated|missing"):
        PromptTemplate((INSTRUCTION,), (KEY_FACT,), (("door", "[0-9"),))


def test_a_merged_contract_takes_a_field_worded_two_ways_and_nothing_else():
    numbered = PromptTemplate(("count the blinks.",), ("the lamp blinked {count}.",), (("count", NUMBER),))
    worded = PromptTemplate(("press the button.",), ("the lamp blinked {count}.", HELD))
    merged = PromptTemplate.merged([numbered, worded])
    assert merged.instructions == ("count the blinks.", "press the button.")
    assert merged.fact_templates == ("the lamp blinked {count}.", HELD)
    assert merged.fields == (("count", NUMBER), ("count", WORDS))
    assert parse_prompt("count the blinks. the lamp blinked 3.", merged).field("count") == "3"
    assert parse_prompt("press the button. the lamp blinked three times.", merged).field("count") == "three times"
    with pytest.raises(ValueError, match="matches no trained template"):
        parse_prompt("press the button. the lamp blinked -3.", merged)  # neither takes a sign
    with pytest.raises(ValueError, match="matches no trained template"):
        parse_prompt("count the blinks. the lamp blinked three.", PromptTemplate.merged([numbered]))
    # fields that hold words in every template stay unlisted, as one template's would
    assert PromptTemplate.merged([worded, PromptTemplate((INSTRUCTION,), (KEY_FACT,))]).fields == ()
