"""MIKASA-Robo-VLA's GatherAndRecall1-VLA-v0 as an sb3-memret task: the colour of a lamp's brief flash, seen while the
robot works, must be remembered until the work is done.

The prospective-memory task. The env is MIKASA's own (``mikasa-robo-suite``), with its protocol:
``pd_ee_delta_pose``, 128x128 cameras, the ``normalized_dense`` reward, success counted once per episode,
evaluation at seeds 4242424242 + i. MIKASA's wrapper table gives it no ``CurriculumPhaseNoopActionWrapper``:
actions act from the first step. The lamp's bulb is a mesh that MIKASA's wheel leaves out: ``lamp_asset`` puts the
project's copy of MIKASA's file in place before the env is made.

**Episode:** a red cube stands on the robot's right, a grey disc (12 cm radius) lies on its left, a row of three
buttons (red, green, blue) between the robot and the disc, and a lamp beyond the disc. The robot must put the cube on
the disc; when the cube first gets there (its xy within 10 cm of the disc's centre, moving slower than 15 cm/s), the
lamp flashes red, green or blue for 8-14 control steps, then turns white again. With the cube on the disc the robot
must press the button of the flash's colour. A press counts only while the cube is on the disc, and the first one
decides: the right colour succeeds, a wrong one fails; either ends the episode. Episodes last up to 200 control
steps.

**Randomisations** (MIKASA's): the flash's colour (uniform over the three) and length; the disc's centre (x 0-8 cm,
y 10-18 cm), which places the cube (8 cm nearer the robot than the disc, at y = -26 cm, +-5 mm), the buttons (22 cm
nearer than the disc, 14 cm apart) and the lamp (24 cm beyond the disc); the arm's initial joints.

**Success:** MIKASA's, at any step: the cube on the disc and the flash's button pressed (the TCP within 4 cm of its
axis and 2.5 cm over its cap).

**Facts:** one, read from the base camera at every control step (``read_flash``): the lit bulb is emissive and
renders at the full level of its colour's channel (255, the other two <= 3), which nothing else in the scene
reaches (the red cube's faces render at 231 and 148); the colour of at least ``MIN_FLASH_PIXELS`` such pixels is
written as ``the flash was green.``. Over 20 expert episodes at development seeds 5000-5019 (912 frames, 214 of
them lit) every lit frame read its colour and no other frame read one; the flash was first read at steps 24-26
(``lab/2026-11-27-gather-and-recall-reader/gather_and_recall_reader.py``). Decoys are worded alike about other things (``the key was blue.``). The
controller sees ``GatherObservation`` only (never ``oracle_info``, nor the lamp), so the colour reaches it only
through its prompt.

**Expert:** ``GatherPressController``: it grasps the cube, sets it on the disc's centre, lets go, rises and presses
the button its prompt's colour names; without a fact it presses the red one (a guess: success at chance). It reads
the cube's, the disc's and the buttons' positions from the env's state, as a detector would report them (a
simulated detector); it never reads the flash.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.controllers.base import Obs
from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
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

LIT_LEVEL = 250  # the lit bulb's channel renders at 255; the red cube's faces at 231 and 148
DARK_LEVEL = 30  # ... and its other two channels at most 3
MIN_FLASH_PIXELS = 8  # the lit bulb covered 85-110 pixels at 128x128 where measured
MIN_VOTE_SHARE = 0.8  # lit pixels that disagree more than this are not read


def read_flash(rgb: np.ndarray) -> str | None:
    """The colour the lamp flashes in one base-camera frame (H, W, 3) uint8, or None while it is white: the colour
    of the pixels lit to the full level of one channel with the other two dark."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"expected one (H, W, 3) frame, got shape {rgb.shape}")
    pixels = rgb.reshape(-1, 3).astype(np.int16)
    channel = pixels.argmax(axis=1)
    others = np.sort(pixels, axis=1)[:, 1]  # the brighter of the other two
    lit = (pixels.max(axis=1) >= LIT_LEVEL) & (others <= DARK_LEVEL)
    scale = rgb.shape[0] * rgb.shape[1] / 128 ** 2
    if lit.sum() < MIN_FLASH_PIXELS * scale:
        return None
    votes = np.bincount(channel[lit], minlength=3)
    best = int(votes.argmax())
    return FLASH_COLOURS[best] if votes[best] >= MIN_VOTE_SHARE * votes.sum() else None


class GatherObservation(DetectorObservation):
    """A GatherAndRecall observation cut to a controller's view: the joints, the hand, the cameras, the buttons by
    colour (``extra/button_positions`` (B, 3, 3), their bases' centres, and ``extra/button_visible``), the cube
    (``extra/cube_position``, (B, 3)) and the disc's centre (``extra/disc_position``, (B, 3)). The lamp and the
    flash's colour are not among them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, lambda base: base.button_bases, "button")
        batch = int(getattr(env.unwrapped, "num_envs", 1))
        for name in ("cube_position", "disc_position"):
            self.observation_space["extra"][name] = spaces.Box(-np.inf, np.inf, (batch, 3), np.float32)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        base, like = self.env.unwrapped, obs["extra"]["tcp_pose"]
        out["extra"]["cube_position"] = stack_positions([base.cubes[0].pose.p], like=like)[:, 0]
        out["extra"]["disc_position"] = stack_positions([base.disc.pose.p], like=like)[:, 0]
        return out


class GatherAndRecallTask(MikasaCueTask):
    """MIKASA-Robo-VLA's GatherAndRecall1-VLA-v0: put the cube on the disc, then press the flash's button."""

    field, detector_key, truth_attribute = "colour", "button", "flash_color"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, "was", CUE_FACT
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, FLASH_COLOURS
    observation_wrapper: ClassVar = GatherObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives GatherAndRecall none
    max_control_steps = EPISODE_STEPS

    def __init__(self, env_id: str = "GatherAndRecall1-VLA-v0"):
        if env_id != "GatherAndRecall1-VLA-v0":
            raise ValueError(f"unknown GatherAndRecall task {env_id!r}; expected 'GatherAndRecall1-VLA-v0' (the "
                             "expert places one cube)")
        super().__init__(env_id, len(FLASH_COLOURS))

    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, obs_mode: str = "rgb",
                 render_backend: str = "cpu", **kwargs: Any) -> gym.Env:
        from sb3_memret.tasks.mikasa.core.lamp_asset import install_lamp_asset

        install_lamp_asset()  # the lamp's bulb mesh, which MIKASA's wheel leaves out
        return super().make_env(max_episode_steps=max_episode_steps, num_envs=num_envs, obs_mode=obs_mode,
                                render_backend=render_backend, **kwargs)

    def read_cue(self, rgb: np.ndarray) -> str | None:
        return read_flash(rgb)

    def expert(self) -> GatherPressController:
        """The gather-and-press expert; without a fact it presses the red button, a guess (success at chance)."""
        return GatherPressController(PROMPT_TEMPLATE, self.words, default=self.words[0])

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        features = demo_layout.demo_features(self.words, with_images, key="button")
        return demo_layout.with_state_extra(demo_layout.with_state_extra(features, "cube"), "disc")

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        frame = demo_layout.demo_frame(obs, with_images, key="button")
        frame = demo_layout.append_state(frame, obs["extra"]["cube_position"])
        return demo_layout.append_state(frame, obs["extra"]["disc_position"])


__all__ = ["CUE_FACT", "EPISODE_STEPS", "FLASH_COLOURS", "GatherAndRecallTask", "GatherObservation", "INSTRUCTION",
           "PROMPT_TEMPLATE", "read_flash"]
