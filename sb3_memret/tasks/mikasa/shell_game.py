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
onto the table (its colour, through the camera's calibration); when the mugs come down it finds them as the
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

import itertools
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Mapping, NamedTuple, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from scipy import ndimage

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.observation import STATE_KEY
from sb3_memret.memory.schema import Key, MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates
from sb3_memret.tasks.mikasa import demo_layout
from sb3_memret.tasks.mikasa.carry_expert import GRIP_CLOSED, REACH_X
from sb3_memret.tasks.mikasa.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.expert import CONTROL_DT, ScriptedTouchController, TouchGains, named_word, tcp_velocity
from sb3_memret.tasks.mikasa.perception import HIDDEN_Z, REFERENCE_SIZE, DetectorObservation, _stack

# ------------------------------------------------------------------------------------------ the asset
YCB_DIR = "assets/mani_skill2_ycb"  # ManiSkill's "ycb" data source, under its ASSET_DIR
MUG_FILES = ("info_pick_v0.json", "models/025_mug/collision.ply", "models/025_mug/textured.obj")
DOWNLOAD_HINT = "python -m mani_skill.utils.download_asset ycb"


def maniskill_asset_dir() -> Path:
    """ManiSkill's ASSET_DIR as ``mani_skill/__init__.py`` sets it ($MS_ASSET_DIR/data, else ~/.maniskill/data),
    read without importing ManiSkill, whose import builds every env (seconds)."""
    return Path(os.getenv("MS_ASSET_DIR", os.path.join(os.path.expanduser("~"), ".maniskill"))) / "data"


def ycb_mug_missing() -> str | None:
    """Why the ShellGame tasks cannot run here (the first file of the YCB mug that ManiSkill lacks, and how to
    get it), or None when ManiSkill has the mug."""
    root = maniskill_asset_dir() / YCB_DIR
    missing = next((root / name for name in MUG_FILES if not (root / name).is_file()), None)
    if missing is None:
        return None
    return (f"MIKASA's ShellGame tasks need ManiSkill's YCB mug model, missing at {missing}; get it with "
            f"`{DOWNLOAD_HINT}`, or set MS_ASSET_DIR to a folder whose data/{YCB_DIR} has it")


# ------------------------------------------------------------------------------------------ the variants
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


def ball_entity(colour: str, n_colours: int) -> str:
    """The fact's entity for the ball of ``colour``: ``ball`` where there is one, ``red ball`` among three."""
    return BALL if n_colours == 1 else f"{colour} {BALL}"


def cup_fact(entity: str, side: str) -> str:
    return FACT_TEMPLATE.format(entity=entity, side=side)


# ------------------------------------------------------------------------------------------ what the camera sees
BALL_RADIUS = 0.02  # m: a ball's centre lies this high (MIKASA's BALL_RADIUS)
CUP_PLANE_Z = 0.05  # m: a cup's pixels are cast onto this plane, about its centre (estimated, see above)
BALL_MIN_LEVEL = 60  # a ball pixel's own channel is at least this ...
BALL_MAX_RATIO = 0.25  # ... and each other channel at most this share of it (the table's wood: >= 0.34, measured)
MIN_BALL_PIXELS = 3  # a ball covers ~14 pixels at 128x128
CHANGE_LEVEL = 40  # a pixel changed when a channel moved by more than this since the reference frame (estimated)
MIN_CUP_PIXELS = 40  # a mug covers ~70-300 pixels at 128x128 (estimated); the lamp's bulb ~25, a finger's twitch less
MAX_CUP_AREA = 4.0  # a changed blob this many times the largest mug at the first sighting is no single mug
MAX_CUP_STEP = 0.45  # m a cup may move between two read frames: across the widest swap (40 cm) and the cast's error
REST_TOL = 0.03  # m from a place in the row: the cup rests there
IDLE_TOL = 0.08  # m a cup may seem to move while it stands: MIKASA lifts all three during a swap (6 cm at most), and
#   the cast onto the plane puts a lifted cup up to ~6 cm nearer the robot
MID_TOL = 0.04  # m a swapping pair's midpoint may seem to move (the lift's shift differs a little across the row)
MAX_TURN = 0.9 * np.pi  # the most a swapping pair may turn between two read frames (a few merged frames skipped)


class CameraFrame(NamedTuple):
    """One base-camera frame and the camera's calibration: what the writer reads of a control step."""

    rgb: np.ndarray  # (H, W, 3) uint8
    intrinsic: np.ndarray  # (3, 3) OpenCV
    extrinsic: np.ndarray  # (3, 4) world to camera, OpenCV axes


def table_point(pixel: Sequence[float], intrinsic: np.ndarray, extrinsic: np.ndarray,
                plane_z: float) -> np.ndarray | None:
    """The world (x, y) where the camera ray through ``pixel`` (row, col, continuous: a pixel's centre is its index
    + 0.5) meets the plane ``z = plane_z``, or None when it does not (looking away from it)."""
    rotation, translation = np.asarray(extrinsic)[:, :3], np.asarray(extrinsic)[:, 3]
    ray = rotation.T @ (np.linalg.inv(np.asarray(intrinsic)) @ np.array([pixel[1], pixel[0], 1.0]))
    origin = -rotation.T @ translation
    if abs(ray[2]) < 1e-9 or (plane_z - origin[2]) / ray[2] <= 0:
        return None
    return (origin + (plane_z - origin[2]) / ray[2] * ray)[:2]


def _scale(rgb: np.ndarray) -> float:
    """Pixel counts measured at 128x128, scaled to this frame's size."""
    return rgb.shape[0] * rgb.shape[1] / REFERENCE_SIZE ** 2


def ball_mask(rgb: np.ndarray, colour: str) -> np.ndarray:
    """Pixels of the ``colour`` ball (red, green, blue: MIKASA's pure colours on a shaded sphere)."""
    if colour not in LAMP_COLOURS:
        raise ValueError(f"unknown ball colour {colour!r}; expected one of {list(LAMP_COLOURS)}")
    rgb = np.asarray(rgb).astype(np.int16)
    own = rgb[..., LAMP_COLOURS.index(colour)]
    others = np.delete(rgb, LAMP_COLOURS.index(colour), axis=-1).max(axis=-1)
    return (own >= BALL_MIN_LEVEL) & (others <= BALL_MAX_RATIO * own)


def ball_on_table(seen: CameraFrame, colour: str) -> np.ndarray | None:
    """Where the ``colour`` ball lies (its centre's x, y), or None when it is out of sight."""
    mask = ball_mask(seen.rgb, colour)
    if mask.sum() < MIN_BALL_PIXELS * _scale(seen.rgb):
        return None
    return table_point(np.argwhere(mask).mean(axis=0) + 0.5, seen.intrinsic, seen.extrinsic, BALL_RADIUS)


def cups_on_table(seen: CameraFrame, reference: np.ndarray, max_pixels: float = np.inf) -> list[tuple[np.ndarray, int]]:
    """The cups in sight, as (x, y) on the table and pixel count: the blobs of pixels that changed since
    ``reference`` (a frame of the same view before the cups came down) with at least ``MIN_CUP_PIXELS`` and at
    most ``max_pixels`` pixels, each blob's centre cast onto the plane about a cup's centre."""
    rgb, reference = np.asarray(seen.rgb), np.asarray(reference)
    if rgb.shape != reference.shape:
        raise ValueError(f"the frame {rgb.shape} and its reference {reference.shape} differ in shape")
    changed = np.abs(rgb.astype(np.int16) - reference.astype(np.int16)).max(axis=-1) > CHANGE_LEVEL
    labels, n_blobs = ndimage.label(changed, structure=np.ones((3, 3)))
    sizes = np.bincount(labels.ravel(), minlength=n_blobs + 1)
    cups = []
    for label in range(1, n_blobs + 1):
        if MIN_CUP_PIXELS * _scale(rgb) <= sizes[label] <= max_pixels:
            point = table_point(np.argwhere(labels == label).mean(axis=0) + 0.5, seen.intrinsic, seen.extrinsic,
                                CUP_PLANE_Z)
            if point is not None:
                cups.append((point, int(sizes[label])))
    return cups


def least_moves(old: np.ndarray, new: np.ndarray) -> tuple[int, ...]:
    """The match of each ``old`` point (n, 2) to a different ``new`` one (m >= n, 2) whose squared moves sum least:
    ``match[i]`` is the new point old point i went to."""
    if len(old) > len(new):
        raise ValueError(f"cannot match {len(old)} points to {len(new)} different ones")
    moves = np.linalg.norm(np.asarray(old)[:, None] - np.asarray(new)[None], axis=-1)
    return min(itertools.permutations(range(len(new)), len(old)),
               key=lambda m: sum(moves[i, j] ** 2 for i, j in enumerate(m)))


def swap_turn(old: np.ndarray, new: np.ndarray) -> float:
    """How far a pair of cups turned about its midpoint between two frames, in radians (-pi, pi], counter-clockwise
    seen from above positive: ``old`` and ``new`` (2, 2) are the pair's positions, cup by cup."""
    before, after = old[0] - old.mean(axis=0), new[0] - new.mean(axis=0)
    return float(np.angle(complex(*after) / complex(*before)))


def follow(cups: np.ndarray, seen: np.ndarray) -> np.ndarray | None:
    """Where each of three cups (3, 2) went among the positions ``seen`` (3, 2), by the law of MIKASA's shuffle: a
    swap turns two cups counter-clockwise (seen from above) about their midpoint, half a turn in all, while the
    third stands (MIKASA lifts all three alike meanwhile, which the cast onto the table shows as a shift toward the
    robot). Of the matches that obey it, the one whose squared moves sum least; None when none does (frames missed
    across a swap's end, or something else moving)."""
    best: tuple[float, np.ndarray] | None = None
    for match in itertools.permutations(range(len(seen))):
        new = seen[list(match)]
        moves = np.linalg.norm(new - cups, axis=1)
        cost = float((moves ** 2).sum())
        if moves.max() <= MAX_CUP_STEP and (best is None or cost < best[0]) and any(
                _one_swap(cups, new, idle) for idle in range(len(cups)) if moves[idle] <= IDLE_TOL):
            best = (cost, new)
    return None if best is None else best[1]


def _one_swap(cups: np.ndarray, new: np.ndarray, idle: int) -> bool:
    """Whether the two cups other than ``idle`` moved as a swapping pair does, once the lift's shift (the standing
    cup's) is taken off: not at all, or turning counter-clockwise about a fixed midpoint by less than ``MAX_TURN``
    (a half turn between two read frames cannot be told from none)."""
    pair = [i for i in range(len(cups)) if i != idle]
    moved = new[pair] - (new[idle] - cups[idle])
    if np.linalg.norm(moved - cups[pair], axis=1).max() <= REST_TOL:
        return True
    return bool(np.linalg.norm(moved.mean(axis=0) - cups[pair].mean(axis=0)) <= MID_TOL
                and 0 < swap_turn(cups[pair], moved) < MAX_TURN)


# ------------------------------------------------------------------------------------------ the writer
class CupWriter:
    """Writes, for each ball, ``the {ball} is under the {side} cup.`` from the base camera's frames (one
    ``CameraFrame`` per control step): the ball's place from the cue, its cup's place in the row once the cups
    have come down, and (``shuffles``) again whenever the tracked cups rest after a swap. One writer serves one
    env; the reset frame (``steps == 0``) starts its episode."""

    relations = {BALL: (MemoryType.OTHER, RELATION)}

    def __init__(self, colours: tuple[str, ...], shuffles: bool):
        self.colours, self.shuffles = colours, shuffles
        self._start()

    def _start(self) -> None:
        self.reference: np.ndarray | None = None  # the latest frame before the cups came down
        self.balls: dict[str, np.ndarray] = {}  # colour -> where the ball lay
        self.places: np.ndarray | None = None  # (3, 2): the row's places, left to right, when the cups came down
        self.cups: np.ndarray | None = None  # (3, 2): where each cup is now, cup i the one first seen at place i
        self.under: dict[str, int] = {}  # colour -> the cup hiding that ball
        self.largest = 0  # the largest cup's pixels at the first sighting
        self.done = False  # nothing more to read this episode

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self._start()
        out = []
        for step, seen in frame.timed_percepts():
            facts = self.see(seen)
            if facts:
                out.append((step, facts))
        return out

    def see(self, seen: CameraFrame) -> Predicates | None:
        """The facts one frame lets the writer state (None: none yet, or nothing new to read)."""
        if self.done:
            return None
        if self.places is None:
            return self._before_cups(seen)
        cups = cups_on_table(seen, self.reference, MAX_CUP_AREA * self.largest)
        if len(cups) != len(SIDES):
            return None  # cups merged, hidden or joined by something else in view: skip the frame
        followed = follow(self.cups, np.stack([point for point, _ in cups]))
        if followed is None:
            return None  # no swap of MIKASA's explains this frame: keep the cups where they were last seen
        self.cups = followed
        return self._facts()

    def _before_cups(self, seen: CameraFrame) -> Predicates | None:
        cups = [] if self.reference is None else cups_on_table(seen, self.reference)
        if not cups:  # the cue: the cups are out of sight; the balls show where they lie
            self.reference = np.asarray(seen.rgb)
            for colour in self.colours:
                point = ball_on_table(seen, colour)
                if point is not None:
                    self.balls[colour] = point
            return None
        if len(cups) != len(SIDES):
            return None  # wait for a frame that shows the three cups apart
        if len(self.balls) != len(self.colours):
            self.done = True  # a ball was never seen: no cup to name
            return None
        order = np.argsort([point[1] for point, _ in cups])  # left (-y) to right
        self.places = np.stack([cups[j][0] for j in order])
        self.cups, self.largest = self.places.copy(), max(size for _, size in cups)
        match = least_moves(np.stack([self.balls[c] for c in self.colours]), self.places)
        self.under = dict(zip(self.colours, match))  # each ball under the cup nearest to where it lay
        facts = self._facts()
        self.done = not self.shuffles
        return facts

    def _facts(self) -> Predicates | None:
        """Each ball's cup's place, when every cup rests at a different place of the row; else None."""
        gaps = np.linalg.norm(self.cups[:, None] - self.places[None], axis=-1)
        at = gaps.argmin(axis=1)
        if len(set(at.tolist())) != len(SIDES) or gaps[np.arange(len(at)), at].max() > REST_TOL:
            return None
        n = len(self.colours)
        return {(BALL, ball_entity(colour, n)): f"{SIDES[at[cup]]} cup" for colour, cup in self.under.items()}


# ------------------------------------------------------------------------------------------ the controller's view
def _mugs(base: Any) -> list[Any]:
    """MIKASA's three mugs (left, center, right as they start)."""
    return [base.mug_left, base.mug_center, base.mug_right]


def _bulbs(base: Any) -> list[Any]:
    """The ColorLamp lamp's coloured bulbs, in ``LAMP_COLOURS`` order (MIKASA parks the dark ones 1000 m up)."""
    return [base.lamp_red, base.lamp_green, base.lamp_blue]


class CupObservation(DetectorObservation):
    """A ShellGame observation cut to a controller's view: joints, hand, cameras, and what a detector of three
    identical cups reports: ``extra/cup_positions`` (B, 3, 3) and ``extra/cup_visible`` (B, 3), the cups in
    sight ordered left to right (by y; hidden ones last, at zero). The detector cannot tell the cups apart, so
    it never says which cup is which: after a shuffle, which cup hides the ball reaches a controller only through
    its prompt."""

    def __init__(self, env: gym.Env):
        super().__init__(env, _mugs, "cup")

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        extra = out["extra"]
        extra["cup_positions"], extra["cup_visible"] = left_to_right(extra["cup_positions"], extra["cup_visible"])
        return out


def left_to_right(positions: Any, visible: Any) -> tuple[Any, Any]:
    """Detections (B, n, 3) and their visibility (B, n) reordered per env by y, the hidden ones last (numpy or
    torch, as given)."""
    if hasattr(positions, "detach"):
        import torch

        order = torch.argsort(positions[..., 1] + 1e6 * (~visible.bool()), dim=1)
        return (torch.gather(positions, 1, order[..., None].expand(-1, -1, positions.shape[-1])),
                torch.gather(visible, 1, order))
    positions, visible = np.asarray(positions), np.asarray(visible)
    order = np.argsort(positions[..., 1] + 1e6 * ~visible.astype(bool), axis=1, kind="stable")
    return np.take_along_axis(positions, order[..., None], axis=1), np.take_along_axis(visible, order, axis=1)


class LampCupObservation(CupObservation):
    """``CupObservation`` plus the lamp, as the camera shows it: ``extra/lamp_visible`` (B, 3), which bulb is lit
    (red, green, blue; none while the lamp is white)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        batch = int(getattr(env.unwrapped, "num_envs", 1))
        self.observation_space["extra"]["lamp_visible"] = spaces.Box(0, 1, (batch, len(LAMP_COLOURS)), np.bool_)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        bulbs = _stack([bulb.pose.p for bulb in _bulbs(self.env.unwrapped)], like=obs["extra"]["tcp_pose"])
        out["extra"]["lamp_visible"] = bulbs[..., 2] < HIDDEN_Z
        return out


# ------------------------------------------------------------------------------------------ the experts
@dataclass(frozen=True)
class CupGains:
    """The cup's geometry as the experts assume it (estimated: the mug was never loaded here) and the push."""

    clearance: float = 0.02  # TCP above the cup's top at a touch (the fingertips reach 9 mm lower)
    max_above: float = 0.072  # TCP at most this far above the cup's centre (MIKASA's touch: within 8 cm of it)
    push_distance: float = 0.1  # push the cup this far in front of the row (MIKASA's hidden goal: 10 cm)
    contact: float = 0.06  # TCP this far behind a cup's centre when pushing it (the mug's radius ~5 cm + a finger)
    backoff: float = 0.11  # start a push from this far behind the cup's centre, clear of its handle
    align: float = 0.015  # the TCP within this of the cup's y (and of the push height) is lined up to push
    pushed: float = 0.02  # the cup within this of the push distance: done, hold still


class CupTouchController(ScriptedTouchController):
    """Touches the cup the prompt's fact names (``the ball is under the left cup.``): its TCP comes down a funnel
    onto a point ``clearance`` above the cup's top and holds still. With ``colours`` (the ColorLamp tasks) the fact
    is the one about the ball of the lamp's colour (``extra/lamp_visible``), and it waits while the lamp is white.
    Without a fact it touches its ``default`` cup, a guess. Stateless: every call re-reads the observation and
    the prompt. The cup's top is taken to lie twice its centre's height up (MIKASA rests a cup at minus its mesh's
    lowest point, its half-height for ManiSkill's centred YCB meshes)."""

    stateful = False

    def __init__(self, prompt_template: PromptTemplate, colours: tuple[str, ...] = (), default: str = DEFAULT_SIDE,
                 chunk_len: int = 8, gains: TouchGains | None = None, cup: CupGains | None = None):
        super().__init__(chunk_len, gains or TouchGains(max_x=REACH_X, ready=(-0.05, 0.0, 0.3)), vocabulary=SIDES,
                         field="side", prompt_template=prompt_template, key="cup", default=default)
        unknown = sorted(set(colours) - set(LAMP_COLOURS))
        if unknown:
            raise ValueError(f"unknown ball colours {unknown}; expected some of {list(LAMP_COLOURS)}")
        self.colours, self.cup = tuple(colours), cup or CupGains()

    def side_of(self, parsed: ParsedPrompt, lamp: np.ndarray | None) -> str | None:
        """The cup to act on: the side the prompt's fact names (the fact about the lamp's colour with ``colours``),
        the default without one; None while the lamp is white."""
        if not self.colours:
            word = named_word(parsed, self.field)
        else:
            lit = [c for c, on in zip(LAMP_COLOURS, lamp) if on] if lamp is not None else []
            if len(lit) != 1:
                return None
            wanted = ball_entity(lit[0], len(self.colours))
            facts = [dict(fact.fields) for fact in parsed.facts]
            word = next((fields.get("side") for fields in facts if fields.get("entity") == wanted), None)
        return word if word in self.vocabulary else self.default

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        extra = obs["extra"]
        if self.colours and "lamp_visible" not in extra:
            raise ValueError("the ColorLamp expert reads the lamp (extra/lamp_visible): wrap the env in "
                             "LampCupObservation")
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        cups = as_numpy(extra["cup_positions"]).astype(np.float64)
        visible = as_numpy(extra["cup_visible"]).astype(bool)
        lamps = as_numpy(extra["lamp_visible"]).astype(bool) if self.colours else [None] * len(prompts)
        velocity = tcp_velocity(as_numpy(obs["agent"]["qpos"]), as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            side = self.side_of(p, lamps[i])
            goal = None
            if side is not None and visible[i].all():  # the detector orders the cups left to right once all are down
                goal = self._goal(tcp[i, :3], cups[i], SIDES.index(side))
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, goal)
        return chunks

    def _goal(self, tcp: np.ndarray, cups: np.ndarray, index: int) -> Any:
        """What a chunk heads for: the cup ``index`` (of the row ``cups``, (3, 3) left to right)."""
        return cups[index]

    def touch_point(self, cup: np.ndarray) -> np.ndarray:
        """Where the TCP touches ``cup`` (its centre): above its top by ``clearance``, within ``max_above`` of it."""
        c = self.cup
        return np.array([cup[0], cup[1], cup[2] + min(cup[2] + c.clearance, c.max_above)])

    def _waypoint(self, pos: np.ndarray, cup: np.ndarray | None) -> np.ndarray:
        """Down a funnel over the touch point (the lowest it may be rises with the distance sideways), never back
        up it; the ready pose while no cup is to be touched."""
        g = self.gains
        if cup is None:
            return np.asarray(g.ready, dtype=np.float64)
        touch = self.touch_point(cup)
        floor = touch[2] + min(g.hover_height, g.funnel_slope * float(np.linalg.norm(touch[:2] - pos[:2])))
        return np.array([touch[0], touch[1], max(touch[2], min(pos[2], floor))])


class PushGoal(NamedTuple):
    """A push chunk's aim: ``approach`` (down a funnel to ``point``, behind the cup), ``push`` (straight to
    ``point``, the cup ahead) or ``hold`` (the cup is there: stay still)."""

    point: np.ndarray
    mode: str


class CupPushController(CupTouchController):
    """Pushes the cup the prompt's fact names forward (+x, away from the robot) by ``push_distance``: it comes down
    behind the cup at the height of its centre, fingers closed, drives forward until the cup stands that far in
    front of the other two (the row it left), then holds still. Without a fact it pushes the default cup."""

    def _goal(self, tcp: np.ndarray, cups: np.ndarray, index: int) -> PushGoal:
        c = self.cup
        cup = cups[index]
        row_x = float(np.mean(np.delete(cups[:, 0], index)))  # the cups left standing mark the row
        height = max(cup[2], 0.03)
        if cup[0] - row_x >= c.push_distance - c.pushed:
            return PushGoal(tcp.copy(), "hold")
        lined_up = abs(tcp[1] - cup[1]) <= c.align and abs(tcp[2] - height) <= c.align and tcp[0] < cup[0]
        if lined_up:
            return PushGoal(np.array([row_x + c.push_distance - c.contact, cup[1], height]), "push")
        return PushGoal(np.array([cup[0] - c.backoff, cup[1], height]), "approach")

    def _waypoint(self, pos: np.ndarray, goal: PushGoal | None) -> np.ndarray:
        g = self.gains
        if goal is None:
            return np.asarray(g.ready, dtype=np.float64)
        if goal.mode == "hold":
            return pos.copy()
        if goal.mode == "push":
            return goal.point
        point = goal.point
        floor = point[2] + min(g.hover_height, g.funnel_slope * float(np.linalg.norm(point[:2] - pos[:2])))
        return np.array([point[0], point[1], max(point[2], min(pos[2], floor))])

    def _grip(self, pos: np.ndarray, goal: Any) -> float:
        return GRIP_CLOSED  # a closed hand pushes as one block


# ------------------------------------------------------------------------------------------ the task
class ShellGameTask(MikasaCueTask):
    """MIKASA-Robo-VLA's ShellGameTouch, ShellGamePush and ShellGameShuffleTouch (``env_id``): remember which
    cup hides the red ball (through the shuffle), then touch it or push it forward."""

    field, detector_key = "side", "cup"
    cue_entity, cue_relation, cue_fact = BALL, RELATION, cup_fact(BALL, "{side}")
    vocabulary = SIDES
    observation_wrapper: ClassVar = CupObservation
    env_ids: ClassVar[tuple[str, ...]] = ("ShellGameTouch-VLA-v0", "ShellGamePush-VLA-v0",
                                          "ShellGameShuffleTouch-VLA-v0")

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
        params = env.unwrapped.get_sensor_params()["base_camera"]
        return CameraFrame(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0],
                           as_numpy(params["intrinsic_cv"])[0], as_numpy(params["extrinsic_cv"])[0])

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
    env_ids: ClassVar[tuple[str, ...]] = ("ShellGameColorLampTouch-VLA-v0", "ShellGameShuffleColorLampTouch-VLA-v0")

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


__all__ = ["CameraFrame", "CupGains", "CupObservation", "CupPushController", "CupTouchController", "CupWriter",
           "FACT_TEMPLATE", "LAMP_COLOURS", "LampCupObservation", "SIDES", "ShellGameColorLampTask", "ShellGameTask",
           "VARIANTS", "ball_mask", "ball_on_table", "cups_on_table", "follow", "left_to_right", "least_moves",
           "maniskill_asset_dir", "shell_game_task", "swap_turn", "table_point", "ycb_mug_missing"]
