"""MIKASA-Robo-VLA's GatherAndRecall 1/3/5/7/9 as sb3-memret tasks: the colour of a lamp's brief flash, seen while
the robot works, must be remembered until the work is done.

The prospective-memory tasks (GatherAndRecall1 short; 3 and 5 medium; 7 and 9 long). The env is MIKASA's own
(``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``, 128x128 cameras, the ``normalized_dense`` reward,
success counted once per episode, evaluation at seeds 4242424242 + i. MIKASA's wrapper table gives them no
``CurriculumPhaseNoopActionWrapper``: actions act from the first step. The lamp's bulb is a mesh that MIKASA's wheel
leaves out: ``lamp_asset`` puts the project's copy of MIKASA's file in place before the env is made.

**Episode:** 1, 3, 5, 7 or 9 cubes (red, green, blue in turn; ``VARIANTS``) stand in rows of three on the robot's
right, a grey disc (12 cm radius) lies on its left, a row of three buttons (red, green, blue) between the robot and
the disc, and a lamp beyond the disc. The robot must put every cube on the disc (a cube is on it with its xy within
10 cm of the disc's centre, moving slower than 15 cm/s); when the k-th cube first gets there (k drawn from 1 to
n - 1, or 1 for one cube), the lamp flashes red, green or blue for 8-14 control steps, then turns white again. With
every cube on the disc the robot must press the button of the flash's colour. A press counts only while every cube
is on the disc, and the first one decides: the right colour succeeds, a wrong one fails; either ends the episode.
Episodes last up to MIKASA's 200, 400, 600, 800 or 1000 control steps.

**Randomisations** (MIKASA's): the flash's colour (uniform over the three), length, and the cube count that
triggers it; the disc's centre (x 0-8 cm, y 10-18 cm), which places the cubes (centred 8 cm nearer the robot than
the disc, at y = -26 cm, 9 cm apart, each +-5 mm), the buttons (22 cm nearer than the disc, 14 cm apart) and the
lamp (24 cm beyond the disc); the arm's initial joints.

**Success:** MIKASA's, at any step: every cube on the disc and the flash's button pressed (the TCP within 4 cm of its
axis and 2.5 cm over its cap).

**Facts:** one, read from the base camera at every control step (``read_lit_colour``): the lit bulb is emissive and
renders at the full level of its colour's channel (255, the other two <= 3), which nothing else in the scene
reaches (the red cube's faces render at 231 and 148); the colour of at least ``MIN_LIT_PIXELS`` such pixels is
written as ``the flash was green.``. Over 20 expert episodes at development seeds 5000-5019 (912 frames, 214 of
them lit) every lit frame read its colour and no other frame read one; the flash was first read at steps 24-26
(``lab/2026-11-27-gather-and-recall-reader/gather_and_recall_reader.py``); with several cubes the green and blue
cubes do not reach the lit level either (tests/test_mikasa_gather_and_recall.py reads every frame of a 3-cube
episode against MIKASA's lamp state). Decoys are worded alike about other things (``the key was blue.``). The
controller sees ``GatherObservation`` only (never ``oracle_info``, nor the lamp), so the colour reaches it only
through its prompt.

**Expert:** ``GatherPressController``: it grasps each cube in turn, sets it on its own place on the disc, lets go,
rises, and once all are placed presses the button its prompt's colour names; without a fact it presses the red one
(a guess: success at chance). It reads the cubes', the disc's and the buttons' positions from the env's state, as a detector would report them (a
simulated detector); it never reads the flash.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.lamp_perception import read_lit_colour
from sb3_memret.tasks.mikasa.gather_and_recall.expert import GatherPressController
from sb3_memret.tasks.mikasa.core.perception import DetectorObservation, stack_positions

# MIKASA's LANGUAGE_INSTRUCTION in the prompt contract's form: lowercase, and its three sentences joined by
# semicolons (the contract reads a prompt's first sentence as the instruction, the rest as facts).
INSTRUCTION = ("move all cubes onto the disc; a lamp will briefly flash while you work; after all cubes are placed, "
               "press the button matching the flash color.")
FACT_TEMPLATE = "the {entity} was {colour}."
CUE_ENTITY = "flash"
CUE_FACT = "the flash was {colour}."
PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(FACT_TEMPLATE,))
FLASH_COLOURS: tuple[str, ...] = ("red", "green", "blue")  # MIKASA's FLASH_COLORS, in order: the buttons' too
EPISODE_STEPS = 200
# MIKASA's variants: the cubes to gather and the episode's control steps (its registered max_episode_steps)
VARIANTS: dict[str, tuple[int, int]] = {"GatherAndRecall1-VLA-v0": (1, 200), "GatherAndRecall3-VLA-v0": (3, 400),
                                        "GatherAndRecall5-VLA-v0": (5, 600), "GatherAndRecall7-VLA-v0": (7, 800),
                                        "GatherAndRecall9-VLA-v0": (9, 1000)}

class GatherObservation(DetectorObservation):
    """A GatherAndRecall observation cut to a controller's view: the joints, the hand, the cameras, the buttons by
    colour (``extra/button_positions`` (B, 3, 3), their bases' centres, and ``extra/button_visible``), the cubes
    (``extra/cube_positions``, (B, n_cubes, 3), in MIKASA's order) and the disc's centre (``extra/disc_position``,
    (B, 3)). The lamp and the flash's colour are not among them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, lambda base: base.button_bases, "button")
        batch, n_cubes = int(getattr(env.unwrapped, "num_envs", 1)), len(env.unwrapped.cubes)
        self.observation_space["extra"]["cube_positions"] = spaces.Box(-np.inf, np.inf, (batch, n_cubes, 3),
                                                                       np.float32)
        self.observation_space["extra"]["disc_position"] = spaces.Box(-np.inf, np.inf, (batch, 3), np.float32)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        base, like = self.env.unwrapped, obs["extra"]["tcp_pose"]
        out["extra"]["cube_positions"] = stack_positions([cube.pose.p for cube in base.cubes], like=like)
        out["extra"]["disc_position"] = stack_positions([base.disc.pose.p], like=like)[:, 0]
        return out


class GatherAndRecallTask(MikasaCueTask):
    """MIKASA-Robo-VLA's GatherAndRecall 1/3/5/7/9 (``VARIANTS``): put every cube on the disc, then press the flash's
    button."""

    field, detector_key, truth_attribute = "colour", "button", "flash_color"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, "was", CUE_FACT
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, FLASH_COLOURS
    observation_wrapper: ClassVar = GatherObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives GatherAndRecall none
    max_control_steps = EPISODE_STEPS

    def __init__(self, env_id: str = "GatherAndRecall1-VLA-v0"):
        if env_id not in VARIANTS:
            raise ValueError(f"unknown GatherAndRecall task {env_id!r}; expected one of {sorted(VARIANTS)}")
        super().__init__(env_id, len(FLASH_COLOURS))
        self.n_cubes, self.max_control_steps = VARIANTS[env_id]

    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, obs_mode: str = "rgb",
                 render_backend: str = "cpu", **kwargs: Any) -> gym.Env:
        from sb3_memret.tasks.mikasa.core.lamp_asset import install_lamp_asset

        install_lamp_asset()  # the lamp's bulb mesh, which MIKASA's wheel leaves out
        return super().make_env(max_episode_steps=max_episode_steps, num_envs=num_envs, obs_mode=obs_mode,
                                render_backend=render_backend, **kwargs)

    def read_cue(self, rgb: np.ndarray) -> str | None:
        return read_lit_colour(rgb)

    def expert(self) -> GatherPressController:
        """The gather-and-press expert; without a fact it presses the red button, a guess (success at chance)."""
        return GatherPressController(PROMPT_TEMPLATE, self.words, default=self.words[0])

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        features = demo_layout.demo_features(self.words, with_images, key="button")
        for name in self._cube_names():
            features = demo_layout.with_state_extra(features, name)
        return demo_layout.with_state_extra(features, "disc")

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        frame = demo_layout.demo_frame(obs, with_images, key="button")
        for i, _ in enumerate(self._cube_names()):
            frame = demo_layout.append_state(frame, as_numpy(obs["extra"]["cube_positions"])[:, i])
        return demo_layout.append_state(frame, obs["extra"]["disc_position"])

    def _cube_names(self) -> list[str]:
        """The demos' state names of the cubes: ``cube`` alone, else ``cube0``, ``cube1``, ..."""
        return ["cube"] if self.n_cubes == 1 else [f"cube{i}" for i in range(self.n_cubes)]


__all__ = ["CUE_FACT", "EPISODE_STEPS", "FLASH_COLOURS", "GatherAndRecallTask", "GatherObservation", "INSTRUCTION",
           "PROMPT_TEMPLATE", "VARIANTS"]
