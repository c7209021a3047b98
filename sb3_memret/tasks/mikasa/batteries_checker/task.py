"""MIKASA-Robo-VLA's BatteriesChecker Easy-3, Easy-6, Hard-3 and Hard-6 as sb3-memret tasks: which batteries have
been checked must be remembered, a checklist that grows as the robot works.

The checklist-memory tasks (Easy-3 medium; the other three long). The env is MIKASA's own (``mikasa-robo-suite``),
with its protocol: ``pd_ee_delta_pose``, 128x128 cameras, the ``normalized_dense`` reward, success counted once
per episode (the env ends an episode at success), evaluation at seeds 4242424242 + i. MIKASA's wrapper table gives
these tasks no ``CurriculumPhaseNoopActionWrapper``: actions act from the first step. The lamp's bulb is a mesh
that MIKASA's wheel leaves out: ``lamp_asset`` puts the project's copy in place before the env is made.

**Episode:** 3 or 6 green batteries (2 cm across, 6 cm tall) stand in the first slots of a 5x3 tray on the robot's
right, in rows of three (slot 1 nearest the camera in the row nearest the robot's right edge); a socket stands
20 cm in front of the tray with a lamp 8 cm beyond it, and a button 24 cm to the tray's left. A check: pick a
battery up, let it go into the socket (MIKASA seats it once it is let go within 1 cm of the socket's centre and
2.5 cm of its height), the lamp lights for 7 steps if the battery works; Easy snaps the battery back to its slot at
once, Hard needs it carried back into its slot (within 2.3 cm); then press the button (the TCP within 7.5 cm of its
axis and 2.51 cm over its cap), which counts the check. Checking a battery again counts nothing. Episodes last 540
(Easy-3), 1080 (Easy-6, Hard-3) or 2160 (Hard-6) control steps.

**Randomisations** (MIKASA's): which batteries work (1 of 3, 3 of 6), the tray's place (x -9 to -1 cm, y -5 to
5 cm), which places the socket, lamp and button; the arm's initial joints.

**Success:** MIKASA's, at any step: every battery in play checked through a complete cycle (so every working one
found), each checked battery within 6.9 cm of its slot.

**Memory:** the checklist, one fact replaced as it grows (``checklist``: ``the battery check found slot 1 dead and
slot 3 working.``), written by ``ChecklistWriter`` from the base camera and the arm's sensors (``writer``); decoys
worded alike about other things (``the fuse check found slot 2 working.``). One fact rather than one per battery:
a controller that takes one memory at a time (K = 1) gets the whole list, as FindImposter's set fact gives it the
whole set. The fixed conditions word MIKASA's own counters at each decision (``facts_now``): ``oracle`` the checks
it counted, ``wrong`` the opposite (every battery not yet checked named checked, with the other lamp word), ``none``
nothing.

**Expert:** ``BatteryCheckController`` checks, one cycle at a time, the first battery its prompt's checklist leaves
out; it reads the batteries, slots, socket and button from the env's state, as a detector would report them (a
simulated detector, ``BatteryObservation``), never the lamp nor which batteries work. Without a checklist it starts
from slot 1 again after every cycle, so it cannot succeed; misled, it checks again what was checked and never what
was not.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, NamedTuple

import gymnasium as gym
import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.tasks.base import EnvFrame, Episode
from sb3_memret.tasks.mikasa.batteries_checker.checklist import (
    CHECK_ENTITY, CHECK_RELATION, CHECKLIST_PATTERN, FACT_TEMPLATE, FIELD, checklist_fact, checklist_value,
    parse_checklist,
)
from sb3_memret.tasks.mikasa.batteries_checker.expert import BatteryCheckController
from sb3_memret.tasks.mikasa.batteries_checker.observation import BatteryObservation
from sb3_memret.tasks.mikasa.batteries_checker.writer import (
    CheckPercept, ChecklistWriter, lamp_lit, read_batteries, read_button,
)
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask

# MIKASA's LANGUAGE_INSTRUCTIONs in the prompt contract's form (lowercase)
EASY_INSTRUCTION = ("find all working batteries by inserting each one into the socket, observing the lamp result, "
                    "and then pressing the button to confirm.")
HARD_INSTRUCTION = ("find all working batteries by inserting each one into the socket, observing the lamp result, "
                    "returning it from the socket to its initial slot, and then pressing the button to confirm.")
PROMPT_TEMPLATE = PromptTemplate(instructions=(EASY_INSTRUCTION, HARD_INSTRUCTION), fact_templates=(FACT_TEMPLATE,),
                                 fields=((FIELD, CHECKLIST_PATTERN),))


@dataclass(frozen=True)
class ChecklistEpisode(Episode):
    """A BatteriesChecker episode's ground truth: the checklist grows as the robot works, so the memory it needs is
    the batteries' checklist whose every check is right (``slot 1 dead`` while only slot 1 is checked), not only
    the whole list it ends with."""

    def is_true(self, entry: MemoryEntry) -> bool:
        ((key, final),) = self.true_facts
        if entry.key != key:
            return False
        truth = parse_checklist(final)
        return all(truth.get(slot) == works for slot, works in parse_checklist(entry.value).items())


class BatteryVariant(NamedTuple):
    """A MIKASA variant: the batteries in play, whether they must be carried back, the episode's control steps."""

    batteries: int
    hard: bool
    steps: int


VARIANTS: dict[str, BatteryVariant] = {
    "BatteriesCheckerEasy-3-VLA-v0": BatteryVariant(3, False, 540),
    "BatteriesCheckerEasy-6-VLA-v0": BatteryVariant(6, False, 1080),
    "BatteriesCheckerHard-3-VLA-v0": BatteryVariant(3, True, 1080),
    "BatteriesCheckerHard-6-VLA-v0": BatteryVariant(6, True, 2160),
}


class BatteriesCheckerTask(MikasaCueTask):
    """MIKASA-Robo-VLA's BatteriesChecker{Easy,Hard}-{3,6}-VLA-v0: check every battery through the socket and the
    button, remembering which have been checked."""

    field, detector_key, truth_attribute = FIELD, "battery", "working_mask"
    cue_entity, cue_relation, cue_fact = CHECK_ENTITY, CHECK_RELATION, FACT_TEMPLATE
    template, vocabulary = PROMPT_TEMPLATE, ()
    observation_wrapper: ClassVar = BatteryObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives these tasks none
    group_name = "working slots"

    def __init__(self, env_id: str = "BatteriesCheckerEasy-3-VLA-v0"):
        if env_id not in VARIANTS:
            raise ValueError(f"unknown BatteriesChecker task {env_id!r}; expected one of {sorted(VARIANTS)}")
        super().__init__(env_id, 0)
        self.variant = VARIANTS[env_id]
        self.max_control_steps = self.variant.steps
        self.instruction_text = HARD_INSTRUCTION if self.variant.hard else EASY_INSTRUCTION

    # ------------------------------------------------------------ simulation
    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, obs_mode: str = "rgb",
                 render_backend: str = "cpu", **kwargs: Any) -> gym.Env:
        from sb3_memret.tasks.mikasa.core.lamp_asset import install_lamp_asset

        install_lamp_asset()  # the lamp's bulb mesh, which MIKASA's wheel leaves out
        return super().make_env(max_episode_steps=max_episode_steps, num_envs=num_envs, obs_mode=obs_mode,
                                render_backend=render_backend, **kwargs)

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        """Each env's frame; its state (privileged: metrics and the fixed conditions only) the slots MIKASA counted
        checked and the slots whose battery works."""
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs, base, n = to_numpy(obs), env.unwrapped, self.variant.batteries
        checked = as_numpy(base.checked_mask)[:, :n]
        working = as_numpy(base.working_mask)[:, :n]
        success = as_numpy(info["success"]).reshape(-1)
        return [EnvFrame(select_obs(obs, i), {"checked": tuple(int(s) + 1 for s in np.flatnonzero(checked[i])),
                                              "working": tuple(int(s) + 1 for s in np.flatnonzero(working[i]))},
                         None, bool(success[i])) for i in range(len(success))]

    def perceive(self, env: gym.Env, obs: Any) -> CheckPercept:
        rgb = as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0]
        tcp = as_numpy(obs["extra"]["tcp_pose"]).reshape(-1)[:3]
        gap = float(as_numpy(obs["agent"]["qpos"]).reshape(-1)[7:9].sum())
        button = read_button(rgb)
        return CheckPercept(tuple(float(v) for v in tcp), gap, lamp_lit(rgb),
                            tuple(tuple(float(v) for v in xy) for xy in read_batteries(rgb, self.variant.batteries)),
                            None if button is None else (float(button[0]), float(button[1])))

    def perception_window(self, env: gym.Env) -> int | None:
        """The whole episode: every check is read."""
        return None

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> ChecklistWriter:
        return ChecklistWriter(self.variant.batteries, self.variant.hard)

    def episode(self, frame: EnvFrame) -> Episode:
        """The whole checklist is the fact to end with; the group is the working batteries' slots."""
        working = frame.state["working"]
        final = checklist_value({slot: slot in working for slot in range(1, self.variant.batteries + 1)})
        return ChecklistEpisode(CHECK_ENTITY, " ".join(map(str, working)), ((self.cue_key, final),),
                                {"working": working})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` checklists of other things' checks (``the fuse check found slot 2 working.``);
        the batteries' own comes only from what the writer saw."""
        words = self._decoy_words(seeding, seeding.location_decoys)
        return [MemoryEntry.create(MemoryType.OTHER, f"{word} check", CHECK_RELATION, self._random_checklist(rng), 0)
                for word in rng.choice(words, size=seeding.location_decoys, replace=False)]

    @staticmethod
    def _decoy_words(seeding: SeedingConfig, need: int) -> list[str]:
        """The things whose checks are decoys: the vocabulary but the battery (``the battery check found ...`` is the
        fact itself, however it is filled in)."""
        words = sorted(set(seeding.vocabulary) - {CHECK_ENTITY.removesuffix(" check")})
        if len(words) < need:
            raise ValueError(f"{need} checklist decoys need {need} things other than the battery in the decoy "
                             f"vocabulary, got {sorted(set(seeding.vocabulary))}")
        return words

    def event_decoy(self, rng: np.random.Generator, now: int, seeding: SeedingConfig) -> MemoryEntry:
        """Another thing's check seen in passing (``the fuse check found slot 2 working.``), worded as the reset's
        decoys are."""
        word = str(rng.choice(self._decoy_words(seeding, 1)))
        return MemoryEntry.create(MemoryType.OTHER, f"{word} check", CHECK_RELATION, self._random_checklist(rng), now)

    def timescale(self, entry: MemoryEntry) -> str:
        """The batteries' checklist holds for the episode; another thing's check (a decoy, an event) only at the
        moment."""
        if entry.type == MemoryType.OTHER and entry.entity != CHECK_ENTITY:
            return "now"
        return super().timescale(entry)

    def _random_checklist(self, rng: np.random.Generator) -> str:
        n = self.variant.batteries
        slots = rng.choice(np.arange(1, n + 1), size=int(rng.integers(1, n + 1)), replace=False)
        return checklist_value({int(slot): bool(rng.integers(2)) for slot in slots})

    # ------------------------------------------------------------ prompts and controllers
    def oracle_facts(self, episode: Episode) -> list[str]:
        """At the start nothing has been checked: no fact."""
        return []

    def wrong_facts(self, episode: Episode) -> list[str]:
        """At the start: every battery named checked, each with the lamp word it does not deserve."""
        return self._wrong(episode, ())

    def facts_now(self, condition: str, episode: Episode, frame: EnvFrame, t: int) -> list[str]:
        """The checklist as MIKASA counts it at ``frame`` (oracle), or its opposite (wrong: every battery not yet
        checked named checked, with the other lamp word; the checked ones left out)."""
        checked = tuple(frame.state["checked"])
        if condition == "wrong":
            return self._wrong(episode, checked)
        if condition != "oracle":
            raise ValueError(f"condition {condition!r} has no facts of its own; expected 'oracle' or 'wrong'")
        working = episode.details["working"]
        return [checklist_fact({slot: slot in working for slot in checked})] if checked else []

    def _wrong(self, episode: Episode, checked: tuple[int, ...]) -> list[str]:
        working = episode.details["working"]
        unchecked = [slot for slot in range(1, self.variant.batteries + 1) if slot not in checked]
        return [checklist_fact({slot: slot not in working for slot in unchecked})] if unchecked else []

    def expert(self) -> BatteryCheckController:
        """The check-cycle expert; without a checklist it checks slot 1 again and again."""
        return BatteryCheckController(self.template, hard=self.variant.hard)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.demo_features(self._slot_names(), with_images, key=self.detector_key)

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.demo_frame(obs, with_images, key=self.detector_key)

    def _slot_names(self) -> tuple[str, ...]:
        return tuple(f"slot{slot}" for slot in range(1, self.variant.batteries + 1))


__all__ = ["BatteriesCheckerTask", "BatteryVariant", "EASY_INSTRUCTION", "HARD_INSTRUCTION", "PROMPT_TEMPLATE",
           "VARIANTS"]
