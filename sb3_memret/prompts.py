"""The prompt contract: instruction + memory texts -> the controller's prompt, and back.

A frozen controller only understands prompts worded exactly like its training prompts, so
every sentence is checked against the declared templates, byte for byte: lowercase, single
spaces, a full stop at the end. Anything else is refused with an error naming the offending
sentence and the accepted forms, never silently passed on.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Sequence

from sb3_memret.envs.cabinet import LAYERS, check_layer

INSTRUCTION = "pick out the cube."
LOCATION_TEMPLATE = "the {entity} is in {value}."
HOLDING_TEMPLATE = "the robot is holding the {value}."
LAYER_VALUE = "drawer layer {layer}"
LAYER_LOCATION_TEMPLATE = LOCATION_TEMPLATE.format(entity="{entity}", value=LAYER_VALUE)
CONDITIONS: tuple[str, ...] = ("oracle", "none", "wrong")

_WORD = r"[a-z]+(?: [a-z]+)*"
_LOCATION_RE = re.compile(rf"the (?P<entity>{_WORD}) is in drawer layer (?P<layer>[0-9]+)\.")
_HOLDING_RE = re.compile(rf"the robot is holding the (?P<value>{_WORD})\.")
_SENTENCE_RE = re.compile(r"[^ .][^.]*\.")


@dataclass(frozen=True)
class PromptTemplate:
    """The sentences a controller was trained on: its instructions and fact templates."""

    instructions: tuple[str, ...] = (INSTRUCTION,)
    fact_templates: tuple[str, ...] = (LAYER_LOCATION_TEMPLATE, HOLDING_TEMPLATE)

    def describe(self) -> str:
        return "instructions " + " | ".join(map(repr, self.instructions)) + "; facts " + " | ".join(
            map(repr, self.fact_templates)
        )


@dataclass(frozen=True)
class LocationFact:
    entity: str
    layer: int


@dataclass(frozen=True)
class HoldingFact:
    value: str


@dataclass(frozen=True)
class ParsedPrompt:
    instruction: str
    facts: tuple[LocationFact | HoldingFact, ...] = field(default_factory=tuple)

    @property
    def layer(self) -> int | None:
        """The drawer layer of the first location fact, or None if no fact names one."""
        return next((f.layer for f in self.facts if isinstance(f, LocationFact)), None)


def location_text(entity: str, layer: int) -> str:
    """The memory text that places ``entity`` in drawer ``layer``."""
    return LOCATION_TEMPLATE.format(entity=entity, value=LAYER_VALUE.format(layer=check_layer(layer)))


def holding_text(value: str) -> str:
    return HOLDING_TEMPLATE.format(value=value)


def build_prompt(instruction: str, memories: Sequence[str], template: PromptTemplate | None = None) -> str:
    """Join an instruction and memory texts into one prompt, checking every sentence."""
    prompt = " ".join([instruction, *memories])
    parse_prompt(prompt, template)
    return prompt


def parse_prompt(prompt: str, template: PromptTemplate | None = None) -> ParsedPrompt:
    """Split a prompt into its instruction and facts, or raise ValueError on any drift."""
    template = template or PromptTemplate()
    if not isinstance(prompt, str):
        raise TypeError(f"prompt must be a str, got {type(prompt).__name__}")
    sentences = _split_sentences(prompt, template)
    instruction, *rest = sentences
    if instruction not in template.instructions:
        raise ValueError(f"prompt {prompt!r} starts with {instruction!r}; expected one of {template.describe()}")
    return ParsedPrompt(instruction, tuple(_parse_fact(s, prompt, template) for s in rest))


def condition_prompt(condition: str, layer: int) -> str:
    """The prompt of a controller-evaluation condition for a cube in ``layer``.

    oracle names the right layer, wrong names another one (the next layer, cyclically),
    none is the bare instruction.
    """
    check_layer(layer)
    if condition == "oracle":
        return build_prompt(INSTRUCTION, [location_text("cube", layer)])
    if condition == "wrong":
        return build_prompt(INSTRUCTION, [location_text("cube", layer % len(LAYERS) + 1)])
    if condition == "none":
        return INSTRUCTION
    raise ValueError(f"unknown condition {condition!r}; expected one of {list(CONDITIONS)}")


def _split_sentences(prompt: str, template: PromptTemplate) -> list[str]:
    sentences = _SENTENCE_RE.findall(prompt)
    if not sentences or " ".join(sentences) != prompt:
        raise ValueError(
            f"malformed prompt {prompt!r}: expected full-stop-terminated sentences separated by single "
            f"spaces, lowercase, with no leading or trailing whitespace; accepted {template.describe()}"
        )
    return sentences


def _parse_fact(sentence: str, prompt: str, template: PromptTemplate) -> LocationFact | HoldingFact:
    if (m := _LOCATION_RE.fullmatch(sentence)) and LAYER_LOCATION_TEMPLATE in template.fact_templates:
        layer = int(m["layer"])
        if layer not in LAYERS:
            raise ValueError(f"memory {sentence!r} in prompt {prompt!r} names drawer layer {layer}; layers are {list(LAYERS)}")
        return LocationFact(m["entity"], layer)
    if (m := _HOLDING_RE.fullmatch(sentence)) and HOLDING_TEMPLATE in template.fact_templates:
        return HoldingFact(m["value"])
    raise ValueError(f"memory {sentence!r} in prompt {prompt!r} matches no trained template; accepted {template.describe()}")
