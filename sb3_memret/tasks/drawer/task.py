"""The drawer task: DrawerCubeTakeOut-v1 behind the Task interface (the seed's testbed).

The target's drawer layer is what must be remembered: the writer reads it from the simulator's
state (``memory_source: seeded``) or from what a camera saw (``observed``), the prompt contract
is ``pick out the {entity}.`` plus ``the {entity} is in drawer layer {layer}.``, and success is
reported per layer.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np

from sb3_memret.controllers.base import RENDER_HINT
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates, Task, check_render_backend
from sb3_memret.tasks.demos import DemoEpisode, PromptMix
from sb3_memret.tasks.drawer.cabinet import LAYERS
from sb3_memret.tasks.drawer.household import Household, HouseholdConfig
from sb3_memret.tasks.drawer.objects import CATALOGUE, OBJECT_SETS, object_set
from sb3_memret.tasks.drawer.prompts import (INSTRUCTION_TEMPLATE, OUTSIDE, OUTSIDE_TEMPLATE, TEMPLATE,
                                           check_prompt_layer, instruction_text, location_text)
from sb3_memret.tasks.drawer.seeding import hearsay_memories, seed_memories
from sb3_memret.tasks.drawer.writer import DrawerWriter, ViewPredicateExtractor

ENV_ID = "DrawerCubeTakeOut-v1"


class DrawerTask(Task):
    """Take the named object out of the one of three drawers the memory says (DrawerCubeTakeOut-v1)."""

    name = "drawer"
    zoo_config = "memret_ppo.yml"
    features = frozenset({"observed", "household", "observe_potential"})
    options = ("objects", "n_objects", "move_probability", "hearsay_per_episode", "glimpses_per_episode")
    max_control_steps = 400
    group_name = "layer"
    wordings = {(MemoryType.OBJECT_LOCATION, OUTSIDE): OUTSIDE_TEMPLATE}  # "the cube is out of the drawers."

    def __init__(self, objects: str | Sequence[str] = "cube", n_objects: int = 1,
                 household: HouseholdConfig = HouseholdConfig()):
        """``objects`` (a named set of ``OBJECT_SETS`` or a list of catalogue objects) and ``n_objects`` of them
        hidden in the drawers, one per drawer; ``household``: how a household lives (with a long-term store)."""
        self.objects = object_set(objects)
        most = min(len(self.objects), len(LAYERS))
        if not 1 <= n_objects <= most:
            raise ValueError(f"n_objects must be in [1, {most}] (one object per drawer, of {list(self.objects)}), "
                             f"got {n_objects}")
        self.n_objects, self.household = n_objects, household

    def new_household(self) -> Household:
        """One env's household of this task's objects (a long-term store's episodes)."""
        return Household(self.objects, self.n_objects, self.household)

    def with_options(self, **options: Any) -> "DrawerTask":
        super().with_options(**options)
        lives = {k: options.pop(k) for k in ("move_probability", "hearsay_per_episode", "glimpses_per_episode")
                 if k in options}
        return DrawerTask(options.get("objects", self.objects), options.get("n_objects", self.n_objects),
                          replace(self.household, **lives))

    def option_checks(self) -> Mapping[str, tuple[type | tuple[type, ...], Any, str]]:
        return {
            "objects": (str, lambda v: v in OBJECT_SETS, f"one of the object sets {sorted(OBJECT_SETS)}"),
            "n_objects": (int, lambda v: 1 <= v <= len(LAYERS), f"an integer in [1, {len(LAYERS)}] (one object per "
                          "drawer)"),
            "move_probability": ((int, float), lambda v: 0 <= v <= 1, "a number in [0, 1]"),
            "hearsay_per_episode": (int, lambda v: v >= 0, "an integer >= 0"),
            "glimpses_per_episode": (int, lambda v: 0 <= v <= len(LAYERS), f"an integer in [0, {len(LAYERS)}] "
                                     "(drawers looked into)"),
        }

    @property
    def config_key(self) -> str:
        return "sb3_memret/DrawerRecall-v0"

    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, obs_mode: str = "state_dict",
                 render_backend: str = "none", **kwargs: Any) -> gym.Env:
        import sb3_memret.tasks.drawer.drawer_cube  # noqa: F401  (registers DrawerCubeTakeOut-v1)

        if max_episode_steps is not None:
            kwargs["max_episode_steps"] = max_episode_steps
        kwargs.setdefault("objects", self.objects)
        kwargs.setdefault("n_objects", self.n_objects)
        return gym.make(ENV_ID, obs_mode=obs_mode, render_backend=render_backend, num_envs=num_envs, **kwargs)

    def env_kwargs(self, needs_images: bool, render_backend: str) -> dict[str, Any]:
        """The env's own robot (the light Panda) named, so a dataset records which robot its cameras show."""
        from sb3_memret.tasks.drawer.drawer_cube import DEFAULT_ROBOT

        check_render_backend(render_backend)
        if not needs_images:
            return {"obs_mode": "state_dict", "render_backend": render_backend, "robot_uids": DEFAULT_ROBOT}
        if render_backend == "none":
            raise ValueError("needs camera images, so choose a render backend "
                             f"(--render-backend cpu or gpu): {RENDER_HINT}")
        return {"obs_mode": "rgb", "render_backend": render_backend, "robot_uids": DEFAULT_ROBOT}

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        base = env.unwrapped
        state = base.privileged_state()
        views = base.views(state)
        look_in = base.look_in() if reset else None
        obs = to_numpy(obs)
        potential, success = to_numpy(info["potential"]).reshape(-1), to_numpy(info["success"]).reshape(-1)
        return [EnvFrame(select_obs(obs, i), state.select(i), float(potential[i]), bool(success[i]), views=views[i],
                         look_in=None if look_in is None else look_in[i]) for i in range(len(potential))]

    def hearsay(self, rng: np.random.Generator, now: int, seeding: SeedingConfig) -> list[MemoryEntry]:
        return hearsay_memories(self.household.hearsay_per_episode, rng, now, seeding)

    def event_decoy(self, rng: np.random.Generator, now: int, seeding: SeedingConfig) -> MemoryEntry:
        """Something else seen out on the table (``the key is out of the drawers.``): it is put away at any moment."""
        seeding.check_task_objects(CATALOGUE)
        thing = str(rng.choice(sorted(set(seeding.vocabulary))))
        return MemoryEntry.create(MemoryType.OBJECT_LOCATION, thing, "is_in", OUTSIDE, now, wordings=self.wordings)

    def look_in(self, frame: EnvFrame, rng: np.random.Generator, household: bool) -> Predicates:
        """Every drawer opened once, or in a household ``glimpses_per_episode`` of them drawn at random."""
        if not household:
            layers = list(LAYERS)
        elif self.household.glimpses_per_episode:
            layers = sorted(int(layer) for layer in rng.choice(LAYERS, size=self.household.glimpses_per_episode,
                                                                replace=False))
        else:
            return {}
        if frame.look_in is None:
            raise RuntimeError("the observed-memory variant needs the reset frame's look_in views")
        return ViewPredicateExtractor.look_in(frame.look_in[[layer - 1 for layer in layers]],
                                              frame.state.object_names[0], layers)

    def timescale(self, entry: MemoryEntry) -> str:
        """Where an object was seen in a drawer lasts (a household's objects stay put between tasks)."""
        if entry.type == MemoryType.OBJECT_LOCATION and entry.value.startswith("drawer layer"):
            return "lasting"
        if entry.type == MemoryType.OBJECT_LOCATION and entry.value == OUTSIDE:  # out on the table: of the moment
            return "now"
        return super().timescale(entry)

    def writer(self, source: str = "seeded") -> DrawerWriter:
        return DrawerWriter(source)

    def episode(self, frame: EnvFrame) -> Episode:
        layer, target = int(frame.state.target_layer[0]), frame.state.target_name()
        key = (MemoryType.OBJECT_LOCATION, target, "is_in")
        return Episode(target, str(layer), ((key, f"drawer layer {layer}"),), {"target_layer": layer})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        return seed_memories(frame.state.placed(), episode.target, rng, seeding, facts=facts)

    @property
    def prompt_template(self) -> PromptTemplate:
        return TEMPLATE

    @property
    def instruction_templates(self) -> tuple[str, ...]:
        return (INSTRUCTION_TEMPLATE,)

    def instruction(self, episode: Episode) -> str:
        return instruction_text(episode.target)

    def oracle_facts(self, episode: Episode) -> list[str]:
        return [location_text(episode.target, episode.details["target_layer"])]

    def wrong_facts(self, episode: Episode) -> list[str]:
        return [location_text(episode.target, episode.details["target_layer"] % len(LAYERS) + 1)]

    def expert(self):
        from sb3_memret.tasks.drawer.expert import ScriptedDrawerController

        return ScriptedDrawerController()

    def chosen_groups(self) -> tuple[str, ...]:
        return tuple(str(layer) for layer in LAYERS)

    def group_reset_options(self, group: str) -> dict[str, Any]:
        if str(group) not in self.chosen_groups():
            return super().group_reset_options(str(group))
        return {"target_layer": int(group)}

    def ablations(self) -> Mapping[str, Any]:
        from sb3_memret.tasks.drawer.ablations import ABLATIONS

        return ABLATIONS

    def check_prompt(self, prompt: ParsedPrompt) -> None:
        check_prompt_layer(prompt)

    def plan_demos(self, n: int, seed: int = 0, noise: float = 0.0, noisy_fraction: float = 0.5,
                   mix: PromptMix | None = None) -> list[DemoEpisode]:
        """Target layers cycled and targets over the objects, a mismatched fact naming another layer at random
        (``sb3_memret.tasks.drawer.demos``)."""
        from sb3_memret.tasks.drawer.demos import plan_drawer_episodes

        return plan_drawer_episodes(self.objects, n, seed, noise, noisy_fraction, mix)

    def expert_gave_up(self, expert: Any) -> bool:
        """The expert opened the named drawer, found it empty and holds still."""
        from sb3_memret.tasks.drawer.expert import Phase

        return expert.phases()[0] is Phase.IDLE

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        from sb3_memret.controllers.observation import dataset_features

        return dataset_features(with_images)

    def demo_frame(self, obs: Any, with_images: bool) -> dict[str, np.ndarray]:
        from sb3_memret.controllers.observation import STATE_KEY, camera_images, observation_state

        frame = {STATE_KEY: observation_state(obs)[0]}
        if with_images:
            frame.update({key: images[0] for key, images in camera_images(obs).items()})
        return frame

    def proprio_names(self) -> tuple[str, ...]:
        from sb3_memret.controllers.observation import PROPRIO_NAMES

        return PROPRIO_NAMES


__all__ = ["DrawerTask", "ENV_ID"]
