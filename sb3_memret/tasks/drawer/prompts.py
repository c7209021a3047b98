"""The drawer's prompts: the fact that places an object in a layer, and the controller-evaluation prompts
(oracle / none / wrong) built from it; layers are checked against the cabinet's."""

from __future__ import annotations

from sb3_memret.controllers.prompts import (LAYER_LOCATION_TEMPLATE, PromptTemplate, ParsedPrompt, build_prompt, check_fixed_condition,
                                instruction_text)
from sb3_memret.tasks.drawer.cabinet import LAYERS, check_layer


def location_text(entity: str, layer: int) -> str:
    """The memory text that places ``entity`` in drawer ``layer``."""
    return LAYER_LOCATION_TEMPLATE.format(entity=entity, layer=check_layer(layer))


def condition_prompt(condition: str, layer: int, target: str = "cube") -> str:
    """The prompt of a controller-evaluation condition for ``target`` in ``layer``.

    oracle names the right layer, wrong names another one (the next layer, cyclically),
    none is the bare instruction.
    """
    check_fixed_condition(condition)
    check_layer(layer)
    instruction = instruction_text(target)
    template = PromptTemplate((instruction,))
    if condition == "oracle":
        return build_prompt(instruction, [location_text(target, layer)], template)
    if condition == "wrong":
        return build_prompt(instruction, [location_text(target, layer % len(LAYERS) + 1)], template)
    return instruction  # none


def check_prompt_layer(prompt: ParsedPrompt) -> int | None:
    """The layer ``prompt``'s first location fact names (None: none), or a ValueError if the cabinet has no such
    layer: the prompt contract accepts any number there, a drawer controller only the cabinet's layers."""
    if prompt.layer is not None and prompt.layer not in LAYERS:
        raise ValueError(f"a prompt to {prompt.instruction!r} names drawer layer {prompt.layer}; the cabinet's layers are "
                         f"{list(LAYERS)}")
    return prompt.layer


__all__ = ["check_prompt_layer", "condition_prompt", "location_text"]
