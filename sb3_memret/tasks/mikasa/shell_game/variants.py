"""The ShellGame envs (``Variant``), the short split's five and the medium split's two -Long shuffles: instructions,
lengths, balls, and the fact that names a ball's cup."""

from __future__ import annotations

from dataclasses import dataclass


SIDES: tuple[str, ...] = ("left", "center", "right")  # MIKASA's mug_left (-y), mug_center, mug_right

DEFAULT_SIDE = "center"  # the experts' guess without a fact

LAMP_COLOURS: tuple[str, ...] = ("red", "green", "blue")  # MIKASA's balls and lamp bulbs, in its index order

FACT_TEMPLATE = "the {entity} is under the {side} cup."

RELATION = "is_under_the"  # OTHER's template, "the {entity} {relation} {value}.", with value "{side} cup"

BALL = "ball"

@dataclass(frozen=True)
class Variant:
    """One ShellGame env: its instruction (MIKASA's, lowercased), length, whether the cups shuffle, its balls'
    colours (one red ball, or ColorLamp's three) and what the robot does to the cup."""

    instruction: str
    steps: int
    shuffles: bool
    colours: tuple[str, ...]
    push: bool = False



VARIANTS: dict[str, Variant] = {
    "ShellGameTouch-VLA-v0": Variant("observe which cup hides the ball, wait, then touch that cup.", 30, False,
                                     ("red",)),
    "ShellGamePush-VLA-v0": Variant("observe which cup hides the ball, wait, then push that cup forward.", 30, False,
                                    ("red",), push=True),
    "ShellGameColorLampTouch-VLA-v0": Variant(
        "observe which color is under each cup, then touch the cup matching the lamp color.", 30, False, LAMP_COLOURS),
    "ShellGameShuffleTouch-VLA-v0": Variant(
        "observe which cup hides the ball, track the cups as they shuffle, then touch the correct cup.", 60, True,
        ("red",)),
    "ShellGameShuffleColorLampTouch-VLA-v0": Variant(
        "observe which color is under each cup, track the cups as they shuffle, then touch the cup matching the lamp "
        "color.", 60, True, LAMP_COLOURS),
}
VARIANTS.update({  # the -Long shuffles: MIKASA's 600 steps, worded as the short ones
    name.replace("-VLA-v0", "-Long-VLA-v0"): Variant(VARIANTS[name].instruction, 600, True, VARIANTS[name].colours)
    for name in ("ShellGameShuffleTouch-VLA-v0", "ShellGameShuffleColorLampTouch-VLA-v0")})

def ball_entity(colour: str, n_colours: int) -> str:
    """The fact's entity for the ball of ``colour``: ``ball`` where there is one, ``red ball`` among three."""
    return BALL if n_colours == 1 else f"{colour} {BALL}"



def cup_fact(entity: str, side: str) -> str:
    return FACT_TEMPLATE.format(entity=entity, side=side)


__all__ = ["BALL", "DEFAULT_SIDE", "FACT_TEMPLATE", "LAMP_COLOURS", "RELATION", "SIDES", "VARIANTS", "Variant", "ball_entity", "cup_fact"]
