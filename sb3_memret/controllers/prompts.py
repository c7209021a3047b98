"""The prompt contract: instruction + memory texts -> the controller's prompt, and back.

A frozen controller only understands prompts worded exactly like its training prompts, so
every sentence is checked against the templates the controller declares, byte for byte:
lowercase, single spaces, a full stop at the end. Anything else is refused with an error
naming the offending sentence and the accepted forms, never silently passed on.

An instruction may carry a number of its own (MIKASA's Rotate: ``rotate the peg by {angle_deg} degrees to match
the target angle.``, a new angle every episode): its field values are parsed as a fact's are
(``ParsedPrompt.instruction_fields``).
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from typing import Sequence

# controller-evaluation prompts: the true facts, none, wrong ones (the same at every decision), or the facts the task's
# writer wrote so far in the episode (``sb3_memret.evaluation.rollout.WrittenFacts``: they change as the episode goes)
FIXED_CONDITIONS: tuple[str, ...] = ("oracle", "none", "wrong")
CONDITIONS: tuple[str, ...] = (*FIXED_CONDITIONS, "written")

NUMBER = r"[0-9]+"  # a field that holds a whole number (a drawer layer, a speed in cm/s)
SIGNED_NUMBER = r"-?[0-9]+"  # a field that holds a signed whole number (a rotation in degrees)
WORDS = r"[a-z]+(?: [a-z]+)*"  # what a field holds when its template gives it no pattern
_SENTENCE_RE = re.compile(r"[^ .][^.]*\.")


@dataclass(frozen=True)
class PromptTemplate:
    """The sentences a controller was trained on: its instructions and fact templates, and the fields among them
    that hold something other than words (``fields``: name and pattern, e.g. ``("layer", NUMBER)``). A name listed
    with several patterns takes any of them: the contract of a controller trained on several tasks, where one task
    words ``{count}`` as a number and another as words (``merged``).

    Either may hold fields (``pick out the {entity}.``): a controller trained on several objects
    takes any object word there, while one trained on ``pick out the cube.`` alone takes nothing else.
    """

    instructions: tuple[str, ...]
    fact_templates: tuple[str, ...] = ()
    fields: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        if not self.instructions or isinstance(self.instructions, str):
            raise ValueError(f"a prompt template needs a tuple of instructions, got {self.instructions!r}")
        for name, pattern in self.fields:
            re.compile(pattern)  # a bad pattern fails here, naming itself

    @classmethod
    def merged(cls, templates: Sequence["PromptTemplate"]) -> "PromptTemplate":
        """One contract taking every sentence any of ``templates`` takes: their instructions and fact templates, and
        every pattern each gives a field of its sentences (words where it names none), each once and in order;
        a field that holds words in every template stays unlisted."""
        fields = dict.fromkeys(field for t in templates for field in t.field_patterns())
        typed = {name for name, pattern in fields if pattern != WORDS}
        return cls(tuple(dict.fromkeys(i for t in templates for i in t.instructions)),
                   tuple(dict.fromkeys(f for t in templates for f in t.fact_templates)),
                   tuple((name, pattern) for name, pattern in fields if name in typed))

    def field_patterns(self) -> tuple[tuple[str, str], ...]:
        """Every field of the template's sentences with each pattern it takes (``WORDS`` where ``fields`` names
        none), in order of first appearance."""
        names = dict.fromkeys(name for sentence in (*self.instructions, *self.fact_templates)
                              for name in re.findall(r"\{(\w+)\}", sentence))
        return tuple((name, pattern) for name in names
                     for pattern in [p for n, p in self.fields if n == name] or [WORDS])

    def describe(self) -> str:
        return "instructions " + " | ".join(map(repr, self.instructions)) + "; facts " + " | ".join(
            map(repr, self.fact_templates)
        )


@dataclass(frozen=True)
class Fact:
    """A memory sentence matched to the template it was worded from, with its field values."""

    template: str
    fields: tuple[tuple[str, str], ...]

    def value(self, name: str) -> str | None:
        """The value of field ``name``, or None when the template has no such field."""
        return next((v for k, v in self.fields if k == name), None)


@dataclass(frozen=True)
class ParsedPrompt:
    instruction: str
    facts: tuple[Fact, ...] = ()
    instruction_fields: tuple[tuple[str, str], ...] = ()  # the instruction template's field values, in order

    def field(self, name: str) -> str | None:
        """The value of field ``name`` in the first fact that has one, or None."""
        return next((value for fact in self.facts if (value := fact.value(name)) is not None), None)


def build_prompt(instruction: str, memories: Sequence[str], template: PromptTemplate) -> str:
    """Join an instruction and memory texts into one prompt, checking every sentence."""
    prompt = " ".join([instruction, *memories])
    parse_prompt(prompt, template)
    return prompt


def parse_prompt(prompt: str, template: PromptTemplate) -> ParsedPrompt:
    """Split a prompt into its instruction and facts, or raise ValueError on any drift."""
    if not isinstance(prompt, str):
        raise TypeError(f"prompt must be a str, got {type(prompt).__name__}")
    # a prompt that does not end a sentence is refused before the scan, whose failed matches on a long tail with no
    # full stop take time growing with the square of its length
    sentences = _SENTENCE_RE.findall(prompt) if prompt.endswith(".") else []
    if not sentences or " ".join(sentences) != prompt:
        raise ValueError(
            f"malformed prompt {prompt!r}: expected full-stop-terminated sentences separated by single "
            f"spaces, lowercase, with no leading or trailing whitespace; accepted {template.describe()}"
        )
    instruction, *rest = sentences
    match = next((m for t in template.instructions if (m := _template_regex(t, template.fields).fullmatch(instruction))),
                 None)
    if match is None:
        raise ValueError(f"prompt {prompt!r} starts with {instruction!r}; expected one of {template.describe()}")
    return ParsedPrompt(instruction, tuple(_parse_fact(s, prompt, template) for s in rest),
                        tuple(match.groupdict().items()))


def check_fixed_condition(condition: str) -> str:
    """``condition`` if it gives a fixed prompt (oracle, none, wrong); else a ValueError naming it and what is accepted."""
    if condition == "written":
        raise ValueError("condition 'written' has no fixed prompt: its facts are what the task's writer has written so "
                         "far (sb3_memret.evaluation.rollout.WrittenFacts, evaluate_task_condition); the fixed ones are "
                         f"{list(FIXED_CONDITIONS)}")
    if condition not in FIXED_CONDITIONS:
        raise ValueError(f"unknown condition {condition!r}; expected one of {list(FIXED_CONDITIONS)}")
    return condition


@functools.lru_cache(maxsize=None)
def _template_regex(template: str, fields: tuple[tuple[str, str], ...] = ()) -> re.Pattern:
    """A template like 'the {entity} is in drawer layer {layer}.' as an exact-match regex, each field matching any
    of its patterns in ``fields`` (words when it has none)."""
    patterns: dict[str, list[str]] = {}
    for name, field_pattern in fields:
        patterns.setdefault(name, []).append(f"(?:{field_pattern})")
    parts = re.split(r"\{(\w+)\}", template)
    pattern = "".join(
        re.escape(part) if i % 2 == 0 else f"(?P<{part}>{'|'.join(patterns.get(part, [WORDS]))})"
        for i, part in enumerate(parts)
    )
    return re.compile(pattern)


def _parse_fact(sentence: str, prompt: str, template: PromptTemplate) -> Fact:
    for fact_template in template.fact_templates:
        if m := _template_regex(fact_template, template.fields).fullmatch(sentence):
            return Fact(fact_template, tuple(m.groupdict().items()))
    raise ValueError(f"memory {sentence!r} in prompt {prompt!r} matches no trained template; accepted {template.describe()}")
