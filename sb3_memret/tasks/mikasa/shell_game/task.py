"""MIKASA-Robo-VLA's ShellGame tasks of the short split as sb3-memret tasks: which cup hides the ball (Touch,
Push), which colour is under each cup (ColorLampTouch), both tracked through a shuffle (ShuffleTouch,
ShuffleColorLampTouch).

**Not calibrated on a real frame.** These envs build ManiSkill's YCB mug (``ycb:025_mug``), a download this
machine cannot make, so no frame of them was ever rendered here: the cup reader's thresholds (how much a pixel
must change when a mug comes down, how many pixels a mug covers), the plane a cup's pixels are cast onto, the
ball's colour thresholds on a shaded sphere, and the experts' cup geometry (its half-height as its resting z,
its radius for the push) are estimates from MIKASA's source and from frames of MIKASA's other envs (the same
table, camera and robot: TakeItBack), not measurements. Where the asset exists, check before quoting a figure:
(1) ``cups_on_table`` finds exactly the three mugs in the first frame after the cue, at the 20 cm spacing, and
``ball_on_table`` the ball within ~1 cm in every cue frame (``frames``' privileged state gives the truth);
(2) the writer's fact equals ``Episode.true_facts`` on MIKASA's evaluation seeds, the shuffled ones included,
and stays so while the arm moves over the cups after the shuffle (the tracker keeps reading the frames then;
a cup hidden by the arm is skipped, but a robot blob the size of a cup could be taken for one); (3) the
experts' oracle, none and wrong success (touch: the TCP 2 cm above the cup's top must lie within MIKASA's 8 cm
of the cup's centre; push: the approach must clear the mug's handle). Without the asset, every make of these
tasks refuses in one line naming the missing file and how to get it (``ycb_mug_missing``). No figure on a
stand-in mug is a ShellGame figure.

The envs are MIKASA's own (``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``, 128x128 cameras,
the ``normalized_dense`` reward, success counted once per episode, evaluation at seeds 4242424242 + i. MIKASA's
wrapper table gives all five ``CurriculumPhaseNoopActionWrapper``: actions are zeroed through the cue (and the
shuffle), so the arm stands still until the cups rest.

**Episode:** three identical upside-down mugs (the YCB mug at 1.3x) stand in a row across the table, 20 cm
apart; MIKASA names them left (-y: the base camera's left, the robot's right), center and right, and the facts
use its names. During the cue (1-5 steps) the mugs are lifted out of sight and the ball shows where its cup
will stand: one red ball (Touch, Push, ShuffleTouch) or a red, a green and a blue ball (the ColorLamp tasks).
Then the mugs come down over the balls. The shuffled tasks then swap cups 2-4 times over 20-35 steps (each swap
of a random pair of slots takes ``shuffle // swaps`` steps along a half-circle round the pair's midpoint, all
three cups lifted up to 6 cm meanwhile; the balls are hidden and put back under their cups after it). In the manipulation phase
the robot touches the cup that hides the ball (Touch, ShuffleTouch), pushes it forward (Push), or touches the
cup that hides the ball of the colour a lamp 25 cm in front of the centre cup now shows (the ColorLamp tasks; the
lamp is white before). Episodes last 30 control steps (60 for the shuffled ones).

**Randomisations** (MIKASA's): the row's centre, (x, y) uniform in [-0.1, 0.1] m each; which cup hides the
ball (uniform; ColorLamp fixes red under the left cup, green under the center one and blue under the right one,
so in the unshuffled ColorLamp task the colours' places never change and a controller that learned them needs
no memory); the cue's length; the shuffle's length, number of swaps and pairs; the lamp's colour; the arm's
initial joints (0.02 rad noise).

**Success** (MIKASA's, at any step of the manipulation phase): Touch, ShuffleTouch: the TCP within 8 cm of the
centre of the cup hiding the ball, the arm static (joint speeds < 0.2 rad/s) and no cup moved more than 5 cm
since the cups came down (MIKASA pins the shuffled tasks' cups at their slots every step); ColorLamp tasks: the
TCP within 8 cm of the centre of the cup hiding the lamp's colour, the arm static; Push: the cup hiding the ball
within 9.6 cm of a hidden goal 10 cm in front of (+x) and 3 cm above the ball's start, the arm static (0.3
rad/s); a forward push of about 1 to 19 cm counts.

**Facts:** ``the ball is under the left cup.`` (one: Touch, Push, ShuffleTouch); ``the red ball is under the
left cup.``, ``the green ball ...``, ``the blue ball ...`` (three: the ColorLamp tasks; the lamp shows only
later, so all three must reach the prompt). Decoys are worded alike about other things (``the key is under the
right cup.``). After a shuffle a fact names the cup's place at the end (``the ball is under the right cup.``:
the cup now standing right).

**Writer** (``CupWriter``, every control step, the base camera only): in the cue it casts each ball's pixels
onto the table (its colour, through the camera's shipped calibration); when the mugs come down it finds them as the
pixels that changed since the last cue frame (``cups_on_table``: the arm stands still then) and names, for each
ball, the cup nearest to where the ball lay, by its place in the row. In a shuffle it follows the three cups
from frame to frame by the shuffle's law (``follow``: a swap turns two cups counter-clockwise, seen from above,
half a turn about their midpoint while the third stands; MIKASA lifts all three alike meanwhile, which the cast
shows as a common shift), skipping frames where cups merge in the view (a pair passes in line with the camera),
and whenever the cups rest at the row's three places it writes where each ball's cup now stands. MIKASA poses the
cups where they stood before the last swap for the shuffle's last ``shuffle % swaps`` steps, then at their final
places: identical cups at the same three places, which the tracker reads as the last swap completed, as it did.
It never reads the simulator, ``oracle_info`` or ``task_cue``. On frames drawn through MIKASA's base camera with
its shuffle's motion (``tests/test_mikasa_shell_game.py``'s ``MikasaShuffle``, seeds 1000-1299; box-shaped cups,
no arm) it named the right cup by the end of the shuffle in 300 of 300 episodes: a check of the tracking logic,
not of the reader on MIKASA's pixels.

**Experts** (``CupTouchController``, ``CupPushController``): scripted frozen controllers on ``pd_ee_delta_pose``
that read ``CupObservation`` only (joints, hand, cameras, and a detector of three identical cups: where the cups
are, ordered left to right, never which is which; for the ColorLamp tasks also which colour the lamp shows).
The cup comes only from the prompt's fact (the ColorLamp expert's from the fact about the lamp's colour); without
one they act on the center cup, a guess (chance: 1/3).
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import gymnasium as gym
import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.observation import STATE_KEY
from sb3_memret.memory.schema import Key, MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.base import EnvFrame, Episode
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.shell_game.variants import (BALL, FACT_TEMPLATE, LAMP_COLOURS, RELATION, SIDES, VARIANTS,
                                                         ball_entity, cup_fact)
from sb3_memret.tasks.mikasa.shell_game.tracking import CameraFrame
from sb3_memret.tasks.mikasa.shell_game.views import CupObservation, LampCupObservation
from sb3_memret.tasks.mikasa.shell_game.experts import CupPushController, CupTouchController
from sb3_memret.tasks.mikasa.shell_game.writer import CupWriter
from sb3_memret.tasks.mikasa.shell_game.assets import ycb_mug_missing


class ShellGameTask(MikasaCueTask):
    """MIKASA-Robo-VLA's ShellGameTouch, ShellGamePush and ShellGameShuffleTouch (``env_id``): remember which
    cup hides the red ball (through the shuffle), then touch it or push it forward."""

    field, detector_key = "side", "cup"
    cue_entity, cue_relation, cue_fact = BALL, RELATION, cup_fact(BALL, "{side}")
    vocabulary = SIDES
    observation_wrapper: ClassVar = CupObservation
    env_ids: ClassVar[tuple[str, ...]] = ("ShellGameTouch-VLA-v0", "ShellGamePush-VLA-v0",
                                          "ShellGameShuffleTouch-VLA-v0", "ShellGameShuffleTouch-Long-VLA-v0")

    def __init__(self, env_id: str = "ShellGameTouch-VLA-v0"):
        if env_id not in self.env_ids:
            raise ValueError(f"unknown {type(self).__name__} task {env_id!r}; expected one of {list(self.env_ids)}")
        super().__init__(env_id, len(SIDES))
        self.variant = VARIANTS[env_id]
        self.instruction_text = self.variant.instruction
        self.template = PromptTemplate(instructions=(self.variant.instruction,), fact_templates=(FACT_TEMPLATE,))
        self.max_control_steps = self.variant.steps

    @property
    def entities(self) -> tuple[str, ...]:
        """The facts' entities, one per ball, in ``LAMP_COLOURS`` order."""
        return tuple(ball_entity(colour, len(self.variant.colours)) for colour in self.variant.colours)

    def key(self, entity: str) -> Key:
        return (MemoryType.OTHER, entity, RELATION)

    # ------------------------------------------------------------ simulation
    def make_env(self, **kwargs: Any) -> gym.Env:
        reason = ycb_mug_missing()
        if reason is not None:
            raise FileNotFoundError(f"task {self.name!r}: {reason}")
        return super().make_env(**kwargs)

    def perceive(self, env: gym.Env, obs: Any) -> CameraFrame:
        return CameraFrame(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0], BASE_CAMERA_INTRINSIC,
                           BASE_CAMERA_EXTRINSIC)

    def final_places(self, base: Any, n_envs: int) -> np.ndarray:
        """(n_envs, n_balls): the place (0 left .. 2 right) each ball's cup ends at; privileged, for metrics only."""
        start = as_numpy(base.cup_with_ball_number).reshape(n_envs, 1).astype(int)
        if not self.variant.shuffles:
            return start
        return as_numpy(base.oracle_info).reshape(n_envs, 1).astype(int)  # MIKASA's final slot of the ball's cup

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs = to_numpy(obs)
        success = as_numpy(info["success"]).reshape(-1)
        places = self.final_places(env.unwrapped, len(success))
        return [EnvFrame(select_obs(obs, i), {"sides": tuple(SIDES[p] for p in places[i]),
                                              "target": self.target_side(env.unwrapped, places, i)}, None,
                         bool(success[i])) for i in range(len(success))]

    def target_side(self, base: Any, places: np.ndarray, i: int) -> str:
        """The side of the cup env ``i``'s robot must reach (privileged, for metrics only)."""
        return SIDES[int(places[i, 0])]

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> CupWriter:
        return CupWriter(self.variant.colours, self.variant.shuffles)

    def episode(self, frame: EnvFrame) -> Episode:
        sides, target = frame.state["sides"], frame.state["target"]
        facts = tuple((self.key(entity), f"{side} cup") for entity, side in zip(self.entities, sides))
        return Episode(BALL, target, facts, {"target_side": target, "ball_sides": " ".join(sides)})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` facts worded as the balls' about other things (``the key is under the right
        cup.``); the balls' own facts come only from what the camera saw, whatever ``facts`` says."""
        vocab = sorted(set(seeding.vocabulary))
        return [MemoryEntry.create(MemoryType.OTHER, str(word), RELATION, f"{rng.choice(SIDES)} cup", 0)
                for word in rng.choice(vocab, size=seeding.location_decoys, replace=False)]

    # ------------------------------------------------------------ prompts and controllers
    @staticmethod
    def sides(episode: Episode) -> list[tuple[str, str]]:
        """(entity, side) of each ball's true fact."""
        return [(key[1], value.removesuffix(" cup")) for key, value in episode.true_facts]

    def oracle_facts(self, episode: Episode) -> list[str]:
        return [cup_fact(entity, side) for entity, side in self.sides(episode)]

    def wrong_facts(self, episode: Episode) -> list[str]:
        """Every ball under the next cup to the right (cyclically): a cup that does not hide it."""
        return [cup_fact(entity, SIDES[(SIDES.index(side) + 1) % len(SIDES)]) for entity, side in self.sides(episode)]

    def expert(self) -> CupTouchController:
        """The touch expert (the push expert for Push); without a fact it acts on the center cup, a guess."""
        kind = CupPushController if self.variant.push else CupTouchController
        colours = self.variant.colours if len(self.variant.colours) > 1 else ()
        return kind(self.template, colours)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.demo_features(SIDES, with_images, key="cup")

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.demo_frame(obs, with_images, key="cup")



class ShellGameColorLampTask(ShellGameTask):
    """MIKASA-Robo-VLA's ShellGameColorLampTouch and ShellGameShuffleColorLampTouch (``env_id``): remember which
    colour is under each cup (through the shuffle), then touch the cup of the lamp's colour."""

    observation_wrapper: ClassVar = LampCupObservation
    env_ids: ClassVar[tuple[str, ...]] = ("ShellGameColorLampTouch-VLA-v0", "ShellGameShuffleColorLampTouch-VLA-v0",
                                          "ShellGameShuffleColorLampTouch-Long-VLA-v0")

    def __init__(self, env_id: str = "ShellGameColorLampTouch-VLA-v0"):
        super().__init__(env_id)

    def final_places(self, base: Any, n_envs: int) -> np.ndarray:
        """Ball i starts under cup i (MIKASA's fixed mapping); after a shuffle, MIKASA's slot of mug i at the end."""
        if not self.variant.shuffles:
            return np.tile(np.arange(len(SIDES)), (n_envs, 1))
        slots = as_numpy(base.slot_of_mug).reshape(n_envs, -1, len(SIDES)).astype(int)
        swaps = as_numpy(base.num_swaps_per_env).reshape(n_envs).astype(int)
        return slots[np.arange(n_envs), swaps]

    def target_side(self, base: Any, places: np.ndarray, i: int) -> str:
        lamp = int(as_numpy(base.target_color).reshape(-1)[i])  # the lamp's colour: privileged, for metrics only
        return SIDES[int(places[i, lamp])]

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        features = super().demo_features(with_images)
        state = features[STATE_KEY]
        names = [*state["names"], *(f"lamp_{colour}_visible" for colour in LAMP_COLOURS)]
        return {**features, STATE_KEY: {**state, "shape": (len(names),), "names": names}}

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        frame = super().demo_frame(obs, with_images)
        lamp = as_numpy(obs["extra"]["lamp_visible"]).reshape(-1).astype(np.float32)
        return {**frame, STATE_KEY: np.concatenate([frame[STATE_KEY], lamp])}



def shell_game_task(env_id: str) -> ShellGameTask:
    """The task of the ShellGame env ``env_id`` (one of ``VARIANTS``)."""
    if env_id in ShellGameColorLampTask.env_ids:
        return ShellGameColorLampTask(env_id)
    if env_id in ShellGameTask.env_ids:
        return ShellGameTask(env_id)
    raise ValueError(f"unknown ShellGame task {env_id!r}; expected one of {list(VARIANTS)}")


__all__ = ["ShellGameColorLampTask", "ShellGameTask", "shell_game_task"]
