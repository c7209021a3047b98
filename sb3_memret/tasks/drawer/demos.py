"""The drawer's demonstration plan: target layers cycled, targets cycled over the objects, facts named outright.

What the data holds and keeps out (the held-out tests depend on it):

- **Prompts in the data**: the bare instruction (``pick out the cube.``: the expert opens the top drawer, as the
  seed's finetuned π0.5 does) and single-fact prompts ``pick out the cube. the cube is in drawer layer L.`` for every
  layer L. The named layer is the cube's layer in most episodes and another layer, drawn at random, in the rest (the
  expert opens the named drawer, finds it empty and holds still), so the policy learns to follow the prompt, not the
  cube. With several objects the target cycles over them and the prompts name it (``pick out the tin. the tin is in
  drawer layer L.``).
- **Prompts kept out**: two-memory prompts, other objects' facts, holding facts and any paraphrase of the fact
  sentence, so ``ablate memcount``, ``ablate prompt`` and ``ablate wording`` stay true held-out tests.
"""

from __future__ import annotations

import numpy as np

from sb3_memret.tasks.demos import PROMPT_KINDS, DemoEpisode, PromptMix, check_plan
from sb3_memret.tasks.drawer.cabinet import LAYERS
from sb3_memret.tasks.drawer.prompts import location_text


def plan_drawer_episodes(objects: tuple[str, ...], n: int, seed: int = 0, noise: float = 0.0,
                         noisy_fraction: float = 0.5, mix: PromptMix | None = None) -> list[DemoEpisode]:
    """``n`` episodes with placement seeds ``seed..seed+n-1``, target layers cycling over the layers and targets
    over ``objects``, prompts drawn by ``mix`` (a mismatched fact names one of the other layers at random) and
    ``noisy_fraction`` of them with arm noise ``noise``."""
    check_plan(n, noise, noisy_fraction)
    mix = mix or PromptMix()
    if mix.recalled:
        raise ValueError(f"the drawer's memory holds the target's drawer from the reset (seeded), so a recalled prompt "
                         f"is its matching one: give its share to matching (got recalled={mix.recalled})")
    rng = np.random.default_rng(seed)
    episodes = []
    for k in range(n):
        layer, target = LAYERS[k % len(LAYERS)], objects[(k // len(LAYERS)) % len(objects)]
        kind = PROMPT_KINDS[rng.choice(len(PROMPT_KINDS), p=mix.weights)]
        facts: tuple[str, ...] = ()
        if kind != "bare":
            named = layer if kind == "matching" else int(rng.choice([other for other in LAYERS if other != layer]))
            facts = (location_text(target, named),)
        noisy = rng.random() < noisy_fraction
        episodes.append(DemoEpisode(seed + k, kind, noise if noisy else 0.0, {"target_layer": layer, "target": target},
                                    facts))
    return episodes


__all__ = ["plan_drawer_episodes"]
