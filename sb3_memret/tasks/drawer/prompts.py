"""The drawer's wording: its instruction, the fact that places an object in a layer (or out of the drawers), the
holding facts, the prompt template its controllers are trained on, and the controller-evaluation prompts (oracle /
none / wrong) built from them; layers are checked against the cabinet's."""

from __future__ import annotations

from sb3_memret.controllers.prompts import NUMBER, ParsedPrompt, PromptTemplate, build_prompt, check_fixed_condition
from sb3_memret.memory.schema import NOTHING, SPECIAL_TEXTS, TEMPLATES, MemoryType
from sb3_memret.tasks.drawer.cabinet import LAYERS, check_layer

INSTRUCTION_TEMPLATE = "pick out the {entity}."
INSTRUCTION = INSTRUCTION_TEMPLATE.format(entity="cube")  # the seed's task: the only object is a cube
LAYER_LOCATION_TEMPLATE = TEMPLATES[MemoryType.OBJECT_LOCATION].replace("{value}", "drawer layer {layer}")
OUTSIDE = "outside"  # the location value of an object in no drawer, worded by OUTSIDE_TEMPLATE
OUTSIDE_TEMPLATE = "the {entity} is out of the drawers."
HOLDING_TEMPLATE = TEMPLATES[MemoryType.HOLDING]
HOLDING_NOTHING_TEXT = SPECIAL_TEXTS[(MemoryType.HOLDING, NOTHING)]
FACT_TEMPLATES = (LAYER_LOCATION_TEMPLATE, OUTSIDE_TEMPLATE, HOLDING_TEMPLATE, HOLDING_NOTHING_TEXT)
FIELDS = (("layer", NUMBER),)  # a layer is a number (the cabinet's are checked by ``check_prompt_layer``)


def drawer_template(instructions: tuple[str, ...] = (INSTRUCTION,)) -> PromptTemplate:
    """The drawer's prompt contract with ``instructions`` (the seed's: ``pick out the cube.`` alone; ``(INSTRUCTION_
    TEMPLATE,)``: any object word)."""
    return PromptTemplate(instructions, FACT_TEMPLATES, FIELDS)


TEMPLATE = drawer_template()  # the seed's contract: the cube alone, and every drawer fact
ANY_OBJECT = drawer_template((INSTRUCTION_TEMPLATE,))  # any object word in the instruction


def instruction_text(target: str) -> str:
    """The instruction that names ``target``: ``pick out the {target}.``"""
    return build_prompt(INSTRUCTION_TEMPLATE.format(entity=target), [], ANY_OBJECT)


def holding_text(value: str) -> str:
    return HOLDING_NOTHING_TEXT if value == NOTHING else HOLDING_TEMPLATE.format(value=value)


def location_text(entity: str, layer: int) -> str:
    """The memory text that places ``entity`` in drawer ``layer``."""
    return LAYER_LOCATION_TEMPLATE.format(entity=entity, layer=check_layer(layer))


def named_layer(prompt: ParsedPrompt) -> int | None:
    """The drawer layer of the first fact that names one, or None."""
    layer = prompt.field("layer")
    return None if layer is None else int(layer)


def condition_prompt(condition: str, layer: int, target: str = "cube") -> str:
    """The prompt of a controller-evaluation condition for ``target`` in ``layer``.

    oracle names the right layer, wrong names another one (the next layer, cyclically),
    none is the bare instruction.
    """
    check_fixed_condition(condition)
    check_layer(layer)
    instruction = instruction_text(target)
    template = drawer_template((instruction,))
    if condition == "oracle":
        return build_prompt(instruction, [location_text(target, layer)], template)
    if condition == "wrong":
        return build_prompt(instruction, [location_text(target, layer % len(LAYERS) + 1)], template)
    return instruction  # none


def check_prompt_layer(prompt: ParsedPrompt) -> int | None:
    """The layer ``prompt``'s first location fact names (None: none), or a ValueError if the cabinet has no such
    layer: the prompt contract accepts any number there, a drawer controller only the cabinet's layers."""
    layer = named_layer(prompt)
    if layer is not None and layer not in LAYERS:
        raise ValueError(f"a prompt to {prompt.instruction!r} names drawer layer {layer}; the cabinet's layers are "
                         f"{list(LAYERS)}")
    return layer


__all__ = ["ANY_OBJECT", "FACT_TEMPLATES", "FIELDS", "HOLDING_NOTHING_TEXT", "HOLDING_TEMPLATE", "INSTRUCTION",
           "INSTRUCTION_TEMPLATE", "LAYER_LOCATION_TEMPLATE", "OUTSIDE", "OUTSIDE_TEMPLATE", "TEMPLATE",
           "check_prompt_layer", "condition_prompt", "drawer_template", "holding_text", "instruction_text",
           "location_text", "named_layer"]
