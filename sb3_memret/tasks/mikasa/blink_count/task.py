"""MIKASA-Robo-VLA's BlinkCountButtonPress tasks (Easy, Medium, Hard and their -Long) as sb3-memret tasks: how many
times a lamp blinked must be remembered.

The temporal-memory tasks. The env is MIKASA's own (``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``,
128x128 cameras, the ``normalized_dense`` reward, success counted once per episode, evaluation at seeds
4242424242 + i. MIKASA's wrapper table gives these tasks no ``CurriculumPhaseNoopActionWrapper``: actions act from
the first step (MIKASA counts no press before the cue ends). MIKASA's package leaves out the lamp's bulb mesh, which
the env builds: ``lamp_asset`` puts the project's copy of MIKASA's file in place before the env is made.

**Episode:** a red and a black button (round caps of 3 cm radius on 13 cm square bases) stand side by side, the black one 16 cm to the
robot's left; 22 cm beyond the red one stands a blue lamp, and 20 cm to its right a phase lamp, red through the
cue. After 5-10 dark steps the blue lamp blinks N times (each blink lit 3 steps, then dark 3-5); when the last dark
gap ends the phase lamp turns green. Then the robot must press the red button exactly N times, each press released
and lifted (MIKASA counts a press when the TCP comes within 2.51 cm of the cap's top, within 6.5 cm of its axis,
then rises 8.5 cm above where the press began), and press the black button to submit. Once the lamp is dark again
the count is known only to a memory of the cue. Episodes last 150 (Easy), 200 (Medium), 300 (Hard) or 1200 (every
-Long) control steps; MIKASA's env ends one at success, and at failure: a press beyond N, or a submission with
another count.

**Randomisations** (MIKASA's): N (Easy 1-3, Medium 1-5, Hard 1-7; -Long: 1-10, 10-20, 20-30; uniform); the dark
steps before the first blink (5-10; -Long: 5-50) and after each (3-5); the buttons' place (x -0.15 to -0.05 m,
y -0.12 to 0.12 m, uniform), the lamps' with them; the arm's initial joints.

**Success:** MIKASA's: the black button pressed, no failure before, with exactly N presses counted.

**Facts:** one, read from the base camera at every control step: the blue lamp lit (``lamp_lit``: at least
``MIN_LAMP_PIXELS`` saturated blue pixels, the bulb's (4, 4, 255); nothing else in the scene comes near) and the
phase lamp green (saturated green pixels) are the step's percept, and the writer counts the blue lamp's dark-to-lit
changes. It writes ``the blue lamp blinked three times.`` once the cue is over: when the phase lamp turns green, or
when the blue lamp has been dark for longer than MIKASA's longest gap between blinks (5 steps) after a blink (the
phase lamp hidden). The count is a word (``once``, ``twice``, ``three times``, ...): the prompt contract's number
fields are fixed, and words read as English. Decoys are worded alike about other things (``the key blinked
twice.``). The controller sees ``BlinkCountObservation`` only (never ``oracle_info``, ``task_cue`` nor MIKASA's
press counters), so the count reaches it only through its prompt. Measured at the development seeds 5000-5039
(``lab/2026-11-27-blink-reader-error/blink_reader_error.py``, the arm moving as the expert moves it): 40 of 40 counts right on each task, each
written at the step the phase lamp turned green.

**Progress as memory**: how often the red button was pressed is not in sight (its cap springs back), so a controller
that reads only the current frame and its prompt cannot count its own presses. The writer then also writes them, a
TASK_PROGRESS fact replaced at each press: ``the red button was pressed twice.``. It reads where the red cap stands
from the base camera (``read_red_cap``: its top face's flat colour, cast through the camera's shipped calibration
onto the plane of the cap's top; within 0.21 cm of the simulator's at development seeds 6000-6011) and the TCP from
the arm's own sensors at every control step, and counts as MIKASA does (a press within 6.5 cm of the cap's axis down
to 2.51 cm over its top, counted once the TCP has risen 8.5 cm above where it began, and only once the phase lamp is
green). The written facts carry the expert through 10 of 10 Easy (development seeds 5100-5109) and 8 of 8 Medium
(5000-5007) episodes.

**The expert** (``ButtonPressController``, ``press_expert``) waits over the red button through the cue, then
presses it as many times as its prompt's count, then presses the black button; without a count it presses once, a
guess. It keeps no state: the presses made come from its prompt's progress fact, and whether the hand is on its way
down or up from where it is and how its joints move. It reads the buttons' places and the phase lamp from a
detector, as a camera shows them: the simulated detector of the other MIKASA experts. ``BlinkCountTask(env_id,
progress=False)`` is the task without progress facts, whose expert counts its own presses (state across calls).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from scipy import ndimage

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.observation import STATE_KEY
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.layout_perception import table_points
from sb3_memret.tasks.mikasa.core.perception import HIDDEN_Z, REFERENCE_SIZE, DetectorObservation
from sb3_memret.tasks.mikasa.blink_count.expert import (COUNTS, PRESSED_FACT, ButtonPressController, count_value,
                                                  parse_count)
from sb3_memret.tasks.mikasa.core.sequence_expert import BUTTON_TOP_ABOVE_BASE

# MIKASA's LANGUAGE_INSTRUCTION in the prompt contract's form (lowercase; it parses as is).
INSTRUCTION = ("count how many times the blue lamp blinks, press the red button exactly that many times when the red "
               "lamp turns green, then press the black button to submit your answer.")
FACT_TEMPLATE = "the {entity} blinked {count}."
CUE_ENTITY = "blue lamp"
CUE_RELATION = "blinked"  # OTHER's template, "the {entity} {relation} {value}.", reads FACT_TEMPLATE
CUE_FACT = "the blue lamp blinked {count}."
PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(FACT_TEMPLATE,))
PROGRESS_PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(PRESSED_FACT, FACT_TEMPLATE))
PRESS_ENTITY, PRESSED = "red button", "pressed"  # the progress fact's entity, and its predicate and relation
PROGRESS_WORDINGS = {(MemoryType.TASK_PROGRESS, word): "the {entity} was pressed {value}." for word in COUNTS}


@dataclass(frozen=True)
class BlinkVariant:
    """One of MIKASA's ids: its most blinks (``BLINK_COUNT_RANGE``'s top), episode length and fewest blinks."""

    max_blinks: int
    steps: int
    min_blinks: int = 1


VARIANTS: dict[str, BlinkVariant] = {
    "BlinkCountButtonPressEasy-VLA-v0": BlinkVariant(3, 150),
    "BlinkCountButtonPressMedium-VLA-v0": BlinkVariant(5, 200),
    "BlinkCountButtonPressHard-VLA-v0": BlinkVariant(7, 300),
    # the -Long variants: 5-50 dark steps before the first blink (the others: 5-10)
    "BlinkCountButtonPressEasy-Long-VLA-v0": BlinkVariant(10, 1200),
    "BlinkCountButtonPressMedium-Long-VLA-v0": BlinkVariant(20, 1200, min_blinks=10),
    "BlinkCountButtonPressHard-Long-VLA-v0": BlinkVariant(30, 1200, min_blinks=20),
}
LONGEST_GAP = 5  # MIKASA's BLINK_OFF_STEPS' top (every variant): the longest dark gap between blinks
MIN_LAMP_PIXELS = 8  # a lit bulb covers ~55 pixels at 128x128


def lamp_lit(rgb: np.ndarray, channel: int) -> bool:
    """Whether a lamp of one saturated primary colour (``channel`` 0 red, 1 green, 2 blue) is lit in one frame (H, W,
    3): at least ``MIN_LAMP_PIXELS`` pixels high in that channel and low in the other two (the blue bulb renders as
    about (4, 4, 255), the green phase lamp as (7, 255, 7)); the white bulb, the wood, the buttons and the robot
    never pass."""
    rgb = np.asarray(rgb).astype(np.int16)
    others = [c for c in range(3) if c != channel]
    mask = (rgb[..., channel] >= 150) & (rgb[..., others[0]] <= 80) & (rgb[..., others[1]] <= 80)
    return int(mask.sum()) >= MIN_LAMP_PIXELS


RED_CAP_RGB = (211, 136, 136)  # the red cap's top face as the base camera renders it (flat: one colour everywhere)
CAP_COLOUR_TOL = 16
MIN_CAP_PIXELS = 8  # the top face covers 18-24 pixels at 128x128
BUTTON_BASE_Z = 0.015  # MIKASA's button base centre height
CAP_TOP_Z = BUTTON_BASE_Z + BUTTON_TOP_ABOVE_BASE  # the unpressed cap's top


@dataclass(frozen=True)
class PressRule:
    """MIKASA's press count (``BlinkCountButtonPress``'s ``evaluate``), as TCP heights over the cap's top: a press
    starts within ``xy_radius`` of the cap's axis and ``down`` over its top, the cap is released again above
    ``released``, and the press counts once the TCP has risen ``lift`` above where it started."""

    xy_radius: float = 0.065
    down: float = 0.0251  # 0.03 margin less 0.35 of the cap's 0.014 travel
    released: float = 0.0272  # 0.03 margin less 0.2 of its travel
    lift: float = 0.085  # REQUIRED_LIFT_HEIGHT 0.1 less LIFT_CONFIRM_TOL 0.015


def read_red_cap(rgb: np.ndarray, intrinsic: np.ndarray, extrinsic: np.ndarray) -> np.ndarray | None:
    """The red button's table (x, y) from one base-camera frame (H, W, 3): its cap's top face (the largest blob of
    ``RED_CAP_RGB`` pixels), cast along the camera ray onto the plane of the cap's top; None when not in sight."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"expected one (H, W, 3) frame, got shape {rgb.shape}")
    mask = (np.abs(rgb.astype(np.int16) - np.array(RED_CAP_RGB, dtype=np.int16)) <= CAP_COLOUR_TOL).all(axis=-1)
    labels, n_blobs = ndimage.label(mask, structure=np.ones((3, 3)))
    if n_blobs == 0:
        return None
    sizes = np.bincount(labels.ravel(), minlength=n_blobs + 1)[1:]
    if sizes.max() < MIN_CAP_PIXELS * np.prod(np.array(rgb.shape[:2]) / REFERENCE_SIZE):
        return None
    pixels = np.argwhere(labels == int(sizes.argmax()) + 1).mean(axis=0) + 0.5
    point = table_points(pixels[None], intrinsic, extrinsic, CAP_TOP_Z)[0]
    return point if np.isfinite(point).all() else None


class PressPercept(NamedTuple):
    """One control step as the progress writer reads it: the lamps (the cue writer's percept), the TCP from the
    arm's sensors, and the red cap's (x, y) as the base camera shows it (None: not in sight)."""

    blue: bool
    green: bool
    tcp: tuple[float, float, float]
    red_cap: tuple[float, float] | None


class BlinkWriter:
    """Writes ``the blue lamp blinked three times.`` once per episode, at the control step the cue is seen to end
    (the phase lamp green, or the blue lamp dark for more than ``longest_gap`` steps after a blink), counting the
    blue lamp's dark-to-lit changes until then. Percepts are ``(blue lit, green lit)`` per control step; the reset
    frame (``steps == 0``) starts an episode. No blink seen (or more than ``COUNTS`` words), nothing written.

    With ``progress``, percepts are ``PressPercept``s, and it also writes ``the red button was pressed twice.`` at
    the step each press of the red button counts (``PressRule``, MIKASA's), the fact replaced at every press."""

    def __init__(self, longest_gap: int = LONGEST_GAP, progress: bool = False, rule: PressRule | None = None):
        self.longest_gap, self.progress, self.rule = longest_gap, progress, rule or PressRule()
        self.relations = {"blinks": (MemoryType.OTHER, CUE_RELATION)}
        if progress:
            self.relations[PRESSED] = (MemoryType.TASK_PROGRESS, PRESSED)
        self._start_episode()

    def _start_episode(self) -> None:
        self.blinks, self.lit, self.dark, self.written = 0, False, 0, False
        self.cap: np.ndarray | None = None  # the red cap's (x, y), first seen
        self.presses, self.ready, self.press_start = 0, True, None  # MIKASA's counter, as the writer sees it

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self._start_episode()
        out = []
        for step, percept in frame.timed_percepts():
            blue, green = percept[0], percept[1]
            if self.progress:
                out += [(step, predicates) for predicates in self._press(percept)]
            if self.written:
                continue
            self.blinks += int(blue and not self.lit)
            self.lit, self.dark = blue, 0 if blue else self.dark + 1
            if self.blinks and (green or self.dark > self.longest_gap):
                self.written = True
                if self.blinks <= len(COUNTS):  # more than the words count: nothing the prompt can say
                    out.append((step, {("blinks", CUE_ENTITY): count_value(self.blinks)}))
        return out

    def _press(self, percept: PressPercept) -> list[Predicates]:
        """A press of the red button this step completes (``PressRule``), from the TCP and the cap seen."""
        if not isinstance(percept, PressPercept):
            raise ValueError("a progress writer reads PressPercepts (BlinkCountTask(progress=True).perceive: the TCP "
                             f"and the red cap seen); got {percept!r}")
        if self.cap is None and percept.red_cap is not None:
            self.cap = np.asarray(percept.red_cap, dtype=np.float64)
        if self.cap is None or not percept.green:  # MIKASA counts no press before the phase lamp turns green
            return []
        r, (x, y, z) = self.rule, percept.tcp
        over = z - CAP_TOP_Z if np.hypot(x - self.cap[0], y - self.cap[1]) < r.xy_radius else np.inf
        self.ready |= over >= r.released
        if self.ready and self.press_start is None and over <= r.down:
            self.ready, self.press_start = False, z
        if self.press_start is not None and self.ready and z >= self.press_start + r.lift:
            self.presses, self.press_start = self.presses + 1, None
            if self.presses <= len(COUNTS):
                return [{(PRESSED, PRESS_ENTITY): count_value(self.presses)}]
        return []


class BlinkCountObservation(DetectorObservation):
    """A BlinkCountButtonPress observation cut to a controller's view: the joints, the hand, the cameras, the buttons
    (``extra/button_positions`` (B, 2, 3), the red then the black button's base centre; ``extra/button_visible``)
    and whether the phase lamp shows green (``extra/lamp_green``, (B,)), as the camera shows them. The blue lamp's
    schedule and MIKASA's press counters are not among them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, lambda base: [base.button_base, base.confirm_button_base], "button")
        batch = int(getattr(env.unwrapped, "num_envs", 1))
        self.observation_space["extra"]["lamp_green"] = spaces.Box(0, 1, (batch,), np.bool_)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        green = self.env.unwrapped.phase_lamp_green.pose.p[:, 2] < HIDDEN_Z  # MIKASA parks the dark bulb 1000 m up
        like = out["extra"]["tcp_pose"]
        out["extra"]["lamp_green"] = green.to(like.device) if hasattr(like, "detach") else as_numpy(green)
        return out


class BlinkCountTask(MikasaCueTask):
    """MIKASA-Robo-VLA's BlinkCountButtonPress{Easy,Medium,Hard}[-Long]-VLA-v0: count the blue lamp's blinks, press
    the red button as many times, then the black one."""

    field, detector_key = "count", "button"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, CUE_RELATION, CUE_FACT
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, COUNTS
    observation_wrapper: ClassVar = BlinkCountObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives these tasks none
    perceives_every_step = True  # the blinks are counted over the cue's frames

    def __init__(self, env_id: str = "BlinkCountButtonPressEasy-VLA-v0", progress: bool = True):
        if env_id not in VARIANTS:
            raise ValueError(f"unknown BlinkCountButtonPress task {env_id!r}; expected one of {sorted(VARIANTS)}")
        self.variant = VARIANTS[env_id]
        super().__init__(env_id, self.variant.max_blinks)
        self.max_control_steps = self.variant.steps
        self.progress = progress
        if progress:
            self.template, self.wordings = PROGRESS_PROMPT_TEMPLATE, PROGRESS_WORDINGS

    # ------------------------------------------------------------ simulation
    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, obs_mode: str = "rgb",
                 render_backend: str = "cpu", **kwargs: Any) -> gym.Env:
        from sb3_memret.tasks.mikasa.core.lamp_asset import install_lamp_asset

        install_lamp_asset()
        return super().make_env(max_episode_steps=max_episode_steps, num_envs=num_envs, obs_mode=obs_mode,
                                render_backend=render_backend, **kwargs)

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs = to_numpy(obs)
        blinks = as_numpy(env.unwrapped.target_blinks).reshape(-1)  # privileged: for metrics only
        success = as_numpy(info["success"]).reshape(-1)
        states = [{"blinks": int(b)} for b in blinks]
        if self.progress:  # MIKASA's own press counter: the progress the fixed conditions state (privileged)
            for state, presses in zip(states, as_numpy(env.unwrapped.press_count).reshape(-1)):
                state["presses"] = int(presses)
        return [EnvFrame(select_obs(obs, i), states[i], None, bool(success[i])) for i in range(len(success))]

    def perceive(self, env: gym.Env, obs: Any) -> tuple[bool, bool] | PressPercept:
        rgb = as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0]
        lamps = lamp_lit(rgb, 2), lamp_lit(rgb, 1)
        if not self.progress:
            return lamps
        cap = read_red_cap(rgb, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC)
        tcp = as_numpy(obs["extra"]["tcp_pose"]).reshape(-1)[:3]
        return PressPercept(*lamps, tuple(float(v) for v in tcp), None if cap is None else tuple(float(v) for v in cap))

    def perception_window(self, env: gym.Env) -> int | None:
        """The whole episode with progress (every press is read), else the cue writer's."""
        return None if self.progress else super().perception_window(env)

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> BlinkWriter:
        return BlinkWriter(progress=self.progress)

    def episode(self, frame: EnvFrame) -> Episode:
        value = count_value(frame.state["blinks"])
        return Episode(self.cue_entity, value, ((self.cue_key, value),), {"blinks": frame.state["blinks"]})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` facts worded as the lamp's about other things, each with a count of the task's
        (``the key blinked twice.``); the lamp's own fact comes only from what the camera saw."""
        vocab = sorted(set(seeding.vocabulary))
        return [MemoryEntry.create(MemoryType.OTHER, str(word), self.cue_relation, str(rng.choice(self.words)), 0)
                for word in rng.choice(vocab, size=seeding.location_decoys, replace=False)]

    # ------------------------------------------------------------ prompts and controllers
    def oracle_facts(self, episode: Episode) -> list[str]:
        return [self.cue_fact.format(count=episode.group)]

    def progress_facts(self, frame: EnvFrame) -> list[str]:
        """With progress: ``the red button was pressed twice.`` from MIKASA's press counter, once a press counted."""
        presses = frame.state.get("presses", 0) if self.progress else 0
        return [PRESSED_FACT.format(presses=count_value(min(presses, len(COUNTS))))] if presses else []

    def wrong_facts(self, episode: Episode) -> list[str]:
        """The next count of the variant's range, cyclically (Easy: 1 -> 2 -> 3 -> 1; Medium-Long: 20 -> 10): one
        press too many fails at that press, one too few at the submission."""
        low, high = self.variant.min_blinks, self.variant.max_blinks
        n = parse_count(episode.group)
        return [self.cue_fact.format(count=count_value(low + (n - low + 1) % (high - low + 1)))]

    def expert(self) -> ButtonPressController:
        """The press expert; without a count it presses once, a guess (success at chance)."""
        return ButtonPressController(self.template, default_count=1,
                                     progress_from="prompt" if self.progress else "observation")

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        features = demo_layout.demo_features(("red", "black"), with_images, key="button")
        names = [*features[STATE_KEY]["names"], "lamp_green"]
        return {**features, STATE_KEY: {**features[STATE_KEY], "shape": (len(names),), "names": names}}

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.append_state(demo_layout.demo_frame(obs, with_images, key="button"),
                                        obs["extra"]["lamp_green"])


__all__ = ["BlinkCountObservation", "BlinkCountTask",
           "BlinkVariant", "BlinkWriter", "CAP_TOP_Z", "CUE_FACT", "FACT_TEMPLATE", "INSTRUCTION", "LONGEST_GAP",
           "PROGRESS_PROMPT_TEMPLATE", "PROGRESS_WORDINGS", "PROMPT_TEMPLATE", "PressPercept", "PressRule", "VARIANTS",
           "lamp_lit", "read_red_cap"]
