"""MIKASA's ShellGame tasks without the YCB mug: the one-line refusal that names the missing asset (registry, rollout,
benchmark), the writer's geometry and tracking on frames drawn here through MIKASA's base camera and its shuffle's
motion law, the controller's view, the experts' choice of cup and motion, and the prompt contract. No frame of the
real envs can be rendered here (no mug), so nothing below measures the readers on MIKASA's pixels."""

from __future__ import annotations


import numpy as np
import pytest
import torch
from click.testing import CliRunner
import gymnasium as gym
from gymnasium import spaces

from mikasa_support import MIKASA_MISSING, leaked_keys

pytest.importorskip("mikasa_robo_suite", reason=MIKASA_MISSING)

from sb3_memret.cli import main  # noqa: E402
from sb3_memret.memory.schema import MemoryEntry, MemoryType  # noqa: E402
from sb3_memret.memory.seeding import SeedingConfig  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt, parse_prompt  # noqa: E402
from sb3_memret.tasks import check_task_name, make_task  # noqa: E402
from sb3_memret.tasks.base import EnvFrame  # noqa: E402
from sb3_memret.tasks.mikasa.core.touch_expert import COAST_GAIN, DRIVE_GAIN, POS_SCALE  # noqa: E402
from sb3_memret.tasks.mikasa.shell_game import (  # noqa: E402
    LAMP_COLOURS,
    MUG_FILES,
    SIDES,
    VARIANTS,
    YCB_DIR,
    CameraFrame,
    CupObservation,
    CupPushController,
    CupTouchController,
    CupWriter,
    LampCupObservation,
    ShellGameColorLampTask,
    ShellGameTask,
    ball_on_table,
    cups_on_table,
    follow,
    left_to_right,
    least_moves,
    maniskill_asset_dir,
    shell_game_task,
    swap_turn,
    table_point,
)

TOUCH = "ShellGameTouch-VLA-v0"
SHUFFLE_LAMP = "ShellGameShuffleColorLampTouch-VLA-v0"


# ---------------------------------------------------------------------------------------------------- the asset
@pytest.fixture
def asset_dir(tmp_path, monkeypatch):
    """MS_ASSET_DIR at an empty folder: ManiSkill finds no mug there."""
    monkeypatch.setenv("MS_ASSET_DIR", str(tmp_path))
    return tmp_path / "data" / YCB_DIR


def test_every_shell_game_id_refuses_in_one_line_naming_the_missing_file(asset_dir):
    for env_id in VARIANTS:
        with pytest.raises(ValueError) as err:
            make_task(env_id)
        message = str(err.value)
        assert "\n" not in message and message.startswith(f"task {env_id!r} is not available: ")
        assert str(asset_dir / MUG_FILES[0]) in message and "download_asset ycb" in message and "YCB mug" in message
    (asset_dir / "models" / "025_mug").mkdir(parents=True)
    (asset_dir / MUG_FILES[0]).write_text("{}")
    with pytest.raises(ValueError, match="missing at .*collision.ply"):
        check_task_name(TOUCH)


def test_with_the_mug_in_place_the_tasks_are_made(asset_dir):
    (asset_dir / "models" / "025_mug").mkdir(parents=True)
    for name in MUG_FILES:  # only that the files exist is checked here: nothing is loaded
        (asset_dir / name).write_text("")
    assert check_task_name(TOUCH) == TOUCH
    assert isinstance(make_task(SHUFFLE_LAMP), ShellGameColorLampTask)
    assert type(make_task("ShellGamePush-VLA-v0")) is ShellGameTask


def test_zoo_config_sections_parse_where_the_mug_is(asset_dir):
    from pathlib import Path

    from sb3_memret.training.config import load_config

    (asset_dir / "models" / "025_mug").mkdir(parents=True)
    for name in MUG_FILES:
        (asset_dir / name).write_text("")
    zoo = Path(__file__).resolve().parents[1] / "zoo_configs" / "memret_ppo_mikasa.yml"
    for env_id, variant in VARIANTS.items():
        kwargs = load_config(zoo, env_id).env_kwargs
        assert kwargs["task"] == env_id and kwargs["k"] == len(variant.colours) and kwargs["replan_every"] == 4
        assert kwargs["capacity"] == kwargs["k"] + kwargs["location_decoys"]


def test_without_the_mug_the_env_refuses_too(asset_dir):
    with pytest.raises(FileNotFoundError, match=f"task '{TOUCH}': .*missing at {asset_dir}"):
        ShellGameTask(TOUCH).make_env()


def test_the_asset_folder_is_maniskills():
    import mani_skill

    assert maniskill_asset_dir() == mani_skill.ASSET_DIR


def test_rollout_and_benchmark_report_the_refusal(asset_dir, tmp_path):
    runner = CliRunner()
    result = runner.invoke(main, ["rollout", "--task", TOUCH])
    assert result.exit_code == 2 and str(asset_dir / MUG_FILES[0]) in result.output
    out = tmp_path / "sg"
    result = runner.invoke(main, ["benchmark", "mikasa", "--tasks", TOUCH, "--episodes", "1", "--out", str(out)])
    # the one task asked cannot run: the command fails saying why (within a split the report names it, and the rest
    # plays: tests/test_benchmark.py)
    assert result.exit_code == 1 and "nothing to play: " in result.output, result.output
    assert str(asset_dir / MUG_FILES[0]) in result.output and "download_asset ycb" in result.output
    assert not (out / "results.json").exists()


# ---------------------------------------------------------------------------------------------------- drawn frames
SIZE = 128


def base_camera() -> tuple[np.ndarray, np.ndarray]:
    """MIKASA's base_camera (look_at eye (0.3, 0, 0.6), target (-0.1, 0, 0.1), 90 degrees, 128x128) as OpenCV
    intrinsic and world-to-camera extrinsic; equal to ManiSkill's intrinsic_cv / extrinsic_cv of TakeItBack-VLA-v0
    (measured: every MIKASA env has this camera)."""
    eye, target = np.array([0.3, 0.0, 0.6]), np.array([-0.1, 0.0, 0.1])
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.array([0.0, 1.0, 0.0])  # it looks back at the robot: world +y is the image's right
    rotation = np.stack([right, np.cross(forward, right), forward])
    return np.array([[64.0, 0, 64], [0, 64.0, 64], [0, 0, 1]]), np.hstack([rotation, (-rotation @ eye)[:, None]])


K, E = base_camera()


def project(point: np.ndarray) -> tuple[np.ndarray, float]:
    """The (row, col) a world point lands on (continuous: pixel i spans [i, i + 1)) and its depth."""
    cam = E[:, :3] @ point + E[:, 3]
    u = K @ cam
    return np.array([u[1] / u[2], u[0] / u[2]]), cam[2]


def table(seed: int = 0) -> np.ndarray:
    """A wood-like background: browns whose green is 45-60% of their red (MIKASA's table: >= 34%, measured)."""
    rng = np.random.default_rng(seed)
    red = rng.uniform(140, 200, (SIZE, SIZE))
    return np.stack([red, red * rng.uniform(0.45, 0.6, red.shape), red * 0.33], -1).astype(np.uint8)


def draw_ball(img: np.ndarray, centre: np.ndarray, colour: str, radius: float = 0.02) -> None:
    """A shaded sphere's silhouette: a disk round the centre's projection, its colour's channel 120-231."""
    pixel, depth = project(centre)
    rows, cols = np.mgrid[:SIZE, :SIZE] + 0.5
    inside = np.hypot(rows - pixel[0], cols - pixel[1]) <= K[0, 0] * radius / depth
    shade = np.zeros((SIZE, SIZE, 3))
    shade[..., LAMP_COLOURS.index(colour)] = 231 - 0.8 * np.hypot(rows - pixel[0] + 1, cols - pixel[1]) * 25
    img[inside] = np.clip(shade, 3, 231)[inside].astype(np.uint8)


def draw_cup(img: np.ndarray, centre: np.ndarray, radius: float = 0.052, half_height: float = 0.052) -> None:
    """An upside-down mug as the box round its projected rims, in an off-white."""
    angles = np.linspace(0, 2 * np.pi, 24)
    rim = [centre + np.array([radius * np.cos(a), radius * np.sin(a), dz]) for a in angles
           for dz in (-half_height, half_height)]
    pixels = np.array([project(p)[0] for p in rim])
    (r0, c0), (r1, c1) = np.floor(pixels.min(0)).astype(int), np.ceil(pixels.max(0)).astype(int)
    img[max(r0, 0):max(r1, 0), max(c0, 0):max(c1, 0)] = (205, 200, 190)


def frame(balls: dict[str, np.ndarray] | None = None, cups: list[np.ndarray] = (), twitch: int = 0) -> CameraFrame:
    """A base-camera frame: the table, balls (colour -> centre), cups drawn far to near, and ``twitch`` pixels of
    a finger's settling (less than a cup)."""
    img = table()
    for colour, centre in (balls or {}).items():
        draw_ball(img, centre, colour)
    for cup in sorted(cups, key=lambda c: -project(c)[1]):
        draw_cup(img, cup)
    img[40:40 + twitch, 60] = 255
    return CameraFrame(img, K, E)


def row(centre_xy: tuple[float, float], z: float = 0.052) -> np.ndarray:
    """MIKASA's three cup places (left, center, right) for a row centred at ``centre_xy``."""
    return np.array([[centre_xy[0], centre_xy[1] + dy, z] for dy in (-0.2, 0.0, 0.2)])


def ball_at(place: np.ndarray) -> np.ndarray:
    return np.array([place[0], place[1], 0.02])


def write(writer: CupWriter, frames: list[CameraFrame], replan: int = 4) -> list[tuple[int, dict]]:
    """Feed ``frames`` (one per control step, the reset's first) to ``writer`` as the physics does: the reset frame,
    then chunks of ``replan`` steps; each fact with the control step it was written at."""
    out = [(step, facts) for step, facts in writer.read(EnvFrame({}, None, None, False, 0, percepts=frames[:1]))]
    for start in range(1, len(frames), replan):
        chunk = frames[start:start + replan]
        out += [(start - 1 + step, facts) for step, facts in
                writer.read(EnvFrame({}, None, None, False, len(chunk), percepts=chunk))]
    return out


# ---------------------------------------------------------------------------------------------------- geometry
@pytest.mark.parametrize("xy", [(0.0, 0.0), (0.1, -0.3), (-0.1, 0.3), (0.05, 0.12)])
def test_a_ball_is_placed_on_the_table_through_the_camera(xy):
    centre = np.array([*xy, 0.02])
    seen = frame({"red": centre})
    assert np.linalg.norm(ball_on_table(seen, "red") - centre[:2]) < 0.006
    assert ball_on_table(seen, "green") is None and ball_on_table(frame(), "red") is None  # the wood is no ball


def test_table_point_inverts_the_projection():
    point = np.array([0.07, -0.21, 0.05])
    assert np.allclose(table_point(project(point)[0], K, E, 0.05), point[:2], atol=1e-9)
    assert table_point((-500.0, 64.0), K, E, 0.05) is None  # a ray above the horizon meets no table in front


def test_the_cups_are_what_changed_since_the_cue():
    places = row((0.03, -0.05))
    found = cups_on_table(frame(cups=list(places)), frame().rgb)
    assert len(found) == 3
    xs = sorted(point[1] for point, _ in found)
    assert np.allclose(np.diff(xs), 0.2, atol=0.02)  # the 20 cm spacing survives the cast onto the table
    assert cups_on_table(frame(twitch=6), frame().rgb) == []  # a finger's twitch is no cup


def test_least_moves_matches_one_to_one():
    old = np.array([[0.0, -0.2], [0.0, 0.0], [0.0, 0.2]])
    assert least_moves(old, old[[2, 0, 1]] + 0.01) == (1, 2, 0)
    assert least_moves(np.array([[0.01, 0.19]]), old) == (2,)
    with pytest.raises(ValueError, match="cannot match 3 points to 1"):
        least_moves(old, old[:1])


def test_follow_takes_the_match_that_turns_the_pair_counter_clockwise():
    places = row((0.0, 0.0))[:, :2]
    mid = places[:2].mean(axis=0)  # the left and center cups swap round their midpoint; the right one stands
    for turn in (0.3, 1.5, 2.6):  # MIKASA: mid + R(turn) (start - mid), frames a few steps apart (a half turn
        # between two read frames looks like none: the writer reads every step, a swap takes 5 or more)
        rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
        moved = np.array([mid + rotation @ (places[0] - mid), mid + rotation @ (places[1] - mid), places[2]])
        assert swap_turn(places[:2], moved[:2]) == pytest.approx(turn)
        assert np.allclose(follow(places, moved[[1, 2, 0]]), moved)  # whatever order the cups are seen in
    clockwise = np.array([mid + (places[0] - mid) @ np.array([[0, -1], [1, 0]]), mid - (places[0] - mid) @ np.array(
        [[0, -1], [1, 0]]), places[2]])
    assert swap_turn(places[:2], clockwise[:2]) == pytest.approx(-np.pi / 2)
    followed = follow(places, clockwise)  # a clockwise quarter turn is the other cup's counter-clockwise one
    assert np.allclose(followed[:2], clockwise[[1, 0]])
    lifted = follow(places, places + [-0.05, 0.0])  # all three lifted alike: the cast shifts them toward the robot
    assert np.allclose(lifted, places + [-0.05, 0.0])
    assert follow(places, places + [[0.1, 0.0], [0.15, 0.0], [0.2, 0.0]]) is None  # none stood: no swap of MIKASA's
    drifted = np.array([mid + (places[0] - mid) @ np.array([[0, 1], [-1, 0]]), mid - (places[0] - mid) @ np.array(
        [[0, 1], [-1, 0]]), places[2]]) + [[0.0, 0.06], [0.0, 0.06], [0.0, 0.0]]
    assert follow(places, drifted) is None  # a pair turning about a midpoint that moved sideways is no swap


# ---------------------------------------------------------------------------------------------------- the writer
@pytest.mark.parametrize("centre,under", [((0.0, 0.0), 0), ((0.1, 0.099), 1), ((-0.1, -0.1), 2), ((0.08, -0.02), 1)])
@pytest.mark.parametrize("cue_steps", [1, 5])
def test_the_ball_names_the_cup_that_came_down_over_it(centre, under, cue_steps):
    places = row(centre)
    ball = {"red": ball_at(places[under])}
    frames = [frame(ball, twitch=2 * k) for k in range(cue_steps)] + [frame(cups=list(places))] * 6
    written = write(CupWriter(("red",), shuffles=False), frames)
    assert written == [(cue_steps, {("ball", "ball"): f"{SIDES[under]} cup"})]


def test_colour_lamp_facts_name_each_colours_cup():
    places = row((-0.04, 0.06))
    balls = {"blue": ball_at(places[0]), "red": ball_at(places[1]), "green": ball_at(places[2])}
    written = write(CupWriter(LAMP_COLOURS, shuffles=False), [frame(balls), frame(balls), frame(cups=list(places))])
    assert written == [(2, {("ball", "red ball"): "center cup", ("ball", "green ball"): "right cup",
                            ("ball", "blue ball"): "left cup"})]


def test_no_fact_without_a_sighting_of_the_ball():
    places = row((0.0, 0.0))
    assert write(CupWriter(("red",), shuffles=False), [frame(), frame(cups=list(places))]) == []


class MikasaShuffle:
    """MIKASA's shuffle as its ``_initialize_episode`` draws it and its ``evaluate`` poses the cups (a copy of its
    formulas, for drawing frames here): cue 1-5 steps, shuffle 20-35 steps, 2-4 swaps of uniformly drawn pairs of
    places, each along a half-circle round the pair's midpoint lifted up to 6 cm with smoothstep timing."""

    PAIRS = ((0, 1), (0, 2), (1, 2))

    def __init__(self, rng: np.random.Generator):
        self.places = row(tuple(rng.uniform(-0.1, 0.1, 2)))
        self.cue, self.shuffle, self.swaps = int(rng.integers(1, 6)), int(rng.integers(20, 36)), int(rng.integers(2, 5))
        self.per_swap = self.shuffle // self.swaps
        mug_at = [0, 1, 2]
        self.place_of = [[0, 1, 2]]  # place_of[s][m]: mug m's place after s swaps (MIKASA's slot_of_mug)
        for s in range(4):
            if s < self.swaps:
                a, b = self.PAIRS[int(rng.integers(0, 3))]
                mug_at[a], mug_at[b] = mug_at[b], mug_at[a]
            self.place_of.append([mug_at.index(m) for m in range(3)])

    def cups(self, elapsed: int) -> list[np.ndarray]:
        """Where the three mugs stand at control step ``elapsed`` (none in the cue: MIKASA lifts them 1000 m)."""
        if elapsed < self.cue:
            return []
        if elapsed >= self.cue + self.shuffle:
            return [self.places[self.place_of[self.swaps][m]] for m in range(3)]
        into = elapsed - self.cue
        past_all = into // self.per_swap >= self.swaps
        current = self.swaps - 1 if past_all else min(into // self.per_swap, 3)
        t = 1.0 if past_all else min(max((into - current * self.per_swap) / self.per_swap, 0.0), 1.0)
        progress = t * t * (3 - 2 * t)
        out = []
        for m in range(3):
            before = self.place_of[current][m]
            after = before if past_all else self.place_of[current + 1][m]  # past the last swap MIKASA poses each cup
            start, end = self.places[before], self.places[after]  # at its place before that swap (see the writer)
            mid, half = (start + end) / 2, (start - end) / 2
            x = mid[0] + half[0] * np.cos(np.pi * progress) - half[1] * np.sin(np.pi * progress)
            y = mid[1] + half[1] * np.cos(np.pi * progress) + half[0] * np.sin(np.pi * progress)
            lift = 0.0 if past_all else 0.06 * np.sin(np.pi * progress)
            out.append(np.array([x, y, start[2] + lift]))
        return out

    def frames(self, colours: tuple[str, ...], under: int, steps: int = 60) -> list[CameraFrame]:
        balls = ({"red": ball_at(self.places[under])} if len(colours) == 1 else
                 {c: ball_at(self.places[i]) for i, c in enumerate(colours)})
        return [frame(balls) if k < self.cue else frame(cups=self.cups(k)) for k in range(steps)]


@pytest.mark.parametrize("seed", range(12))
def test_the_shuffle_is_tracked_to_where_the_ball_ends(seed):
    rng = np.random.default_rng(seed)
    shuffle, under = MikasaShuffle(rng), int(rng.integers(0, 3))
    written = write(CupWriter(("red",), shuffles=True), shuffle.frames(("red",), under))
    final = SIDES[shuffle.place_of[shuffle.swaps][under]]
    assert written[0] == (shuffle.cue, {("ball", "ball"): f"{SIDES[under]} cup"})  # the cups came down
    assert written[-1][1] == {("ball", "ball"): f"{final} cup"}
    settled = next(step for step, facts in reversed(written) if facts != written[-1][1]) if any(
        facts != written[-1][1] for _, facts in written) else written[0][0]
    assert settled < shuffle.cue + shuffle.shuffle  # the last change is written before the manipulation starts


@pytest.mark.parametrize("seed", range(4))
def test_the_colour_lamp_shuffle_is_tracked_for_every_colour(seed):
    shuffle = MikasaShuffle(np.random.default_rng(100 + seed))
    written = write(CupWriter(LAMP_COLOURS, shuffles=True), shuffle.frames(LAMP_COLOURS, 0))
    assert written[-1][1] == {("ball", f"{c} ball"): f"{SIDES[shuffle.place_of[shuffle.swaps][i]]} cup"
                              for i, c in enumerate(LAMP_COLOURS)}


def test_a_frame_no_swap_explains_is_skipped():
    places = row((0.0, 0.0))
    writer = CupWriter(("red",), shuffles=True)
    shifted = places + [0.06, 0.0, 0.0]  # all three cups 6 cm forward: no swap moves three
    written = write(writer, [frame({"red": ball_at(places[0])}), frame(cups=list(places)), frame(cups=list(shifted)),
                             frame(cups=list(places))])
    assert written == [(1, {("ball", "ball"): "left cup"}), (3, {("ball", "ball"): "left cup"})]


# ---------------------------------------------------------------------------------------------------- the view
class _Actor:
    def __init__(self, xyz):
        self.pose = type("Pose", (), {"p": torch.tensor([xyz], dtype=torch.float32)})()


class _FakeMikasa:
    """What the view reads of MIKASA's env: its mugs and lamp bulbs (positions only), one env."""

    num_envs = 1

    def __init__(self, mugs, bulbs_z=(1000.06, 0.06, 1000.06)):
        self.mug_left, self.mug_center, self.mug_right = (_Actor(p) for p in mugs)
        self.lamp_red, self.lamp_green, self.lamp_blue = (_Actor([0.3, 0.0, z]) for z in bulbs_z)


class _Source(gym.Env):
    """A raw ManiSkill-layout env over ``_FakeMikasa`` (as the benchmark's PrivilegedView builds one)."""

    def __init__(self, base):
        self._base = base
        box = spaces.Box(-np.inf, np.inf, (1, 9), np.float32)
        self.observation_space = spaces.Dict({
            "agent": spaces.Dict({"qpos": box, "qvel": box}),
            "extra": spaces.Dict({"tcp_pose": spaces.Box(-np.inf, np.inf, (1, 7), np.float32)}),
            "sensor_data": spaces.Dict({"base_camera": spaces.Dict({"rgb": spaces.Box(0, 255, (1, 8, 8, 3),
                                                                                     np.uint8)})}),
        })
        self.action_space = spaces.Box(-1, 1, (7,), np.float32)

    @property
    def unwrapped(self):
        return self._base


def _raw_obs():
    return {"agent": {"qpos": torch.zeros(1, 9), "qvel": torch.zeros(1, 9)},
            "extra": {"tcp_pose": torch.zeros(1, 7), "oracle_info": torch.ones(1), "obj_pose": torch.zeros(1, 7)},
            "sensor_data": {"base_camera": {"rgb": torch.zeros(1, 8, 8, 3, dtype=torch.uint8)}}}


def test_the_view_orders_the_cups_left_to_right_and_never_says_which_is_which():
    # after a shuffle mug_left stands right and mug_right left; in the cue all are lifted out of sight
    view = CupObservation(_Source(_FakeMikasa([[0.0, 0.2, 0.05], [0.0, 0.0, 0.05], [0.0, -0.2, 0.05]])))
    out = view.observation(_raw_obs())
    assert torch.allclose(out["extra"]["cup_positions"][0, :, 1], torch.tensor([-0.2, 0.0, 0.2]))
    assert out["extra"]["cup_visible"].all() and not leaked_keys(out, ("oracle", "obj_pose", "lamp"))
    lifted = CupObservation(_Source(_FakeMikasa([[0.0, 0.2, 1000.05], [0.0, 0.0, 0.05], [0.0, -0.2, 1000.05]])))
    seen = lifted.observation(_raw_obs())["extra"]
    assert seen["cup_visible"].tolist() == [[True, False, False]] and seen["cup_positions"][0, 1:].abs().sum() == 0


def test_left_to_right_with_numpy_keeps_hidden_cups_last():
    positions = np.array([[[0, 0.3, 0], [0, 0, 0], [0, -0.1, 0]]])
    ordered, visible = left_to_right(positions, np.array([[True, False, True]]))
    assert ordered[0, :, 1].tolist() == [-0.1, 0.3, 0] and visible.tolist() == [[True, True, False]]


def test_the_lamp_view_says_which_bulb_is_lit():
    view = LampCupObservation(_Source(_FakeMikasa([[0.0, -0.2, 0.05], [0.0, 0.0, 0.05], [0.0, 0.2, 0.05]])))
    assert view.observation(_raw_obs())["extra"]["lamp_visible"].tolist() == [[False, True, False]]


# ---------------------------------------------------------------------------------------------------- the experts
READY_QPOS = np.array([[0.0, 0, 0, -2 * np.pi / 3, 0, 2 * np.pi / 3, np.pi / 4, 0.04, 0.04]])


def _obs(tcp_xyz, places, lamp=None):
    """A controller observation: the hand pointing down at ``tcp_xyz``, the arm still, the cups at ``places``."""
    extra = {"tcp_pose": np.array([[*tcp_xyz, 0.0, 1.0, 0.0, 0.0]]), "cup_positions": np.asarray(places)[None],
             "cup_visible": np.ones((1, 3), bool)}
    if lamp is not None:
        extra["lamp_visible"] = np.array([[c == lamp for c in LAMP_COLOURS]])
    return {"agent": {"qpos": READY_QPOS, "qvel": np.zeros((1, 9))}, "extra": extra}


def _play(controller, prompt, places, chunks=12, replan=4, push_cup=None):
    """Closed loop on the arm model the experts plan with (the TCP moves 0.243 * delta + 0.378 * its last step per
    control step; still at each replan, as the observation says): the TCP's path. ``push_cup``: the index of a cup
    the hand shoves ahead of it (a 6 cm contact radius) while at its height."""
    tcp, places = np.array([-0.055, 0.0, 0.336]), np.array(places, dtype=float)
    controller.reset([0])
    path = [tcp.copy()]
    for _ in range(chunks):
        step = np.zeros(3)
        for action in controller.act(_obs(tcp, places), [prompt])[0, :replan]:
            step = DRIVE_GAIN * POS_SCALE * action[:3] + COAST_GAIN * step
            tcp = tcp + step
            path.append(tcp.copy())
            if push_cup is not None:
                cup = places[push_cup]
                if abs(tcp[1] - cup[1]) < 0.05 and tcp[2] < 2 * cup[2] and tcp[0] > cup[0] - 0.06:
                    cup[0] = tcp[0] + 0.06
    return np.array(path), places


@pytest.mark.parametrize("side", SIDES)
def test_the_touch_expert_holds_above_the_named_cup_within_mikasas_reach(side):
    task = ShellGameTask(TOUCH)
    places = row((0.05, -0.04))
    prompt = build_prompt(task.instruction_text, [f"the ball is under the {side} cup."], task.template)
    path, _ = _play(task.expert(), prompt, places)
    cup = places[SIDES.index(side)]
    assert np.linalg.norm(path[-1] - cup) < 0.08 and path[-1][2] > 2 * cup[2]  # MIKASA's touch, above the cup's top
    assert np.linalg.norm(path[-1] - path[-5]) < 0.005  # and still
    others = np.delete(places, SIDES.index(side), axis=0)
    near_other = np.linalg.norm(path[:, None, :2] - others[None, :, :2], axis=-1).min(axis=1) < 0.1
    assert not (near_other & (path[:, 2] < 2 * cup[2] + 0.01)).any()  # never lower than a cup's top beside it


def test_without_a_fact_the_expert_guesses_the_center_cup():
    task = ShellGameTask(TOUCH)
    places = row((0.0, 0.0))
    path, _ = _play(task.expert(), task.instruction_text, places)
    assert np.linalg.norm(path[-1][:2] - places[1][:2]) < 0.02


def test_the_colour_lamp_expert_follows_the_fact_about_the_lamps_colour():
    expert = ShellGameColorLampTask().expert()
    template = expert.spec.prompt_template
    facts = ["the red ball is under the right cup.", "the green ball is under the left cup.",
             "the blue ball is under the center cup."]
    parsed = parse_prompt(build_prompt(template.instructions[0], facts, template), template)
    assert [expert.side_of(parsed, np.array([c == lamp for c in LAMP_COLOURS])) for lamp in LAMP_COLOURS] == \
        ["right", "left", "center"]
    assert expert.side_of(parsed, np.zeros(3, bool)) is None  # the lamp is white: no target yet
    bare = parse_prompt(template.instructions[0], template)
    assert expert.side_of(bare, np.array([True, False, False])) == "center"  # no fact about red: a guess
    expert.reset([0])
    places = row((0.0, 0.0))
    chunk = expert.act(_obs([0.0, 0.0, 0.3], places, lamp="green"), [" ".join([template.instructions[0], *facts])])
    assert chunk[0, :, 1].sum() < -1  # heading for the left cup (-y), where the green ball is
    with pytest.raises(ValueError, match="LampCupObservation"):
        expert.act(_obs([0.0, 0.0, 0.3], places), [template.instructions[0]])
    task = ShellGameColorLampTask()
    state = task.demo_frame(_obs([0.0, 0.0, 0.3], places, lamp="green"), False)["observation.state"]
    names = task.demo_features(False)["observation.state"]["names"]
    assert len(state) == len(names) and state[names.index("lamp_green_visible")] == 1
    assert state[names.index("cup_left_y")] == pytest.approx(-0.2)


@pytest.mark.parametrize("side", SIDES)
def test_the_push_expert_comes_down_behind_the_cup_and_pushes_it_forward(side):
    task = ShellGameTask("ShellGamePush-VLA-v0")
    expert = task.expert()
    assert isinstance(expert, CupPushController)
    places = row((-0.05, 0.03))
    index = SIDES.index(side)
    prompt = build_prompt(task.instruction_text, [f"the ball is under the {side} cup."], task.template)
    path, moved = _play(expert, prompt, places, chunks=20, push_cup=index)
    assert 0.05 < moved[index, 0] - places[index, 0] < 0.15  # MIKASA's goal: 10 cm forward, within 9.6 cm
    assert np.allclose(np.delete(moved, index, axis=0), np.delete(places, index, axis=0))  # the others stand
    cup = places[index]
    low = path[:, 2] < 2 * cup[2] + 0.01  # below the cup's top the hand came down behind it, never onto it
    assert (path[low, 0] < cup[0] - 0.05).any() and np.all(np.abs(path[low, 1] - cup[1]) < 0.03)
    assert np.linalg.norm(path[-1] - path[-5]) < 0.005  # done: still
    assert (expert.act(_obs(path[-1], moved), [prompt])[0, :, -1] == -1).all()  # a closed hand


# ---------------------------------------------------------------------------------------------------- the contract
@pytest.mark.parametrize("env_id", list(VARIANTS))
def test_facts_decoys_and_prompts_follow_the_contract(env_id):
    task = shell_game_task(env_id)
    assert task.max_control_steps == VARIANTS[env_id].steps and task.replan_every == 4
    n = len(VARIANTS[env_id].colours)
    places = (("left",), "left") if n == 1 else (("left", "center", "right"), "center")
    episode = task.episode(EnvFrame({}, {"sides": places[0], "target": places[1]}, None, False))
    oracle, wrong = task.oracle_facts(episode), task.wrong_facts(episode)
    assert oracle == (["the ball is under the left cup."] if n == 1 else
                      ["the red ball is under the left cup.", "the green ball is under the center cup.",
                       "the blue ball is under the right cup."])
    assert len(wrong) == n and not set(wrong) & set(oracle)
    decoys = task.seed_memories(EnvFrame({}, None, None, False), episode, np.random.default_rng(0), SeedingConfig())
    written = [MemoryEntry.create(MemoryType.OTHER, entity, "is_under_the", value, 0)
               for (_, entity, _), value in episode.true_facts]
    assert [e.text for e in written] == oracle and all(episode.is_true(e) for e in written)
    assert len(decoys) == 5 and not any(episode.is_true(d) for d in decoys)
    for facts in (oracle, wrong, [d.text for d in decoys], []):
        parse_prompt(build_prompt(task.instruction(episode), facts, task.template), task.expert().spec.prompt_template)
    writer = task.writer()
    assert writer.relations == {"ball": (MemoryType.OTHER, "is_under_the")}
    assert isinstance(task.expert(), CupTouchController)
    assert isinstance(task.expert(), CupPushController) == VARIANTS[env_id].push
    names = task.demo_features(False)["observation.state"]["names"]
    assert "cup_left_x" in names and ("lamp_red_visible" in names) == (n == 3)


def test_other_ids_are_refused():
    with pytest.raises(ValueError, match="unknown ShellGame task 'ShellGamePick-VLA-v0'"):
        shell_game_task("ShellGamePick-VLA-v0")
    with pytest.raises(ValueError, match="unknown ShellGameTask task 'ShellGameColorLampTouch-VLA-v0'"):
        ShellGameTask("ShellGameColorLampTouch-VLA-v0")


def test_the_truth_for_metrics_reads_mikasas_final_slots():
    class Base:  # MIKASA's episode state (privileged: metrics only), two envs
        cup_with_ball_number = torch.tensor([0, 2], dtype=torch.uint8)
        oracle_info = torch.tensor([1, 2], dtype=torch.uint8)
        slot_of_mug = torch.tensor([[[0, 1, 2], [1, 0, 2], [2, 0, 1], [2, 0, 1], [2, 0, 1]],
                                    [[0, 1, 2], [0, 2, 1], [0, 2, 1], [0, 2, 1], [0, 2, 1]]])
        num_swaps_per_env = torch.tensor([2, 1])
        target_color = torch.tensor([0, 1])

    assert ShellGameTask(TOUCH).final_places(Base, 2).tolist() == [[0], [2]]
    assert ShellGameTask("ShellGameShuffleTouch-VLA-v0").final_places(Base, 2).tolist() == [[1], [2]]
    lamp = ShellGameColorLampTask(SHUFFLE_LAMP)
    places = lamp.final_places(Base, 2)
    assert places.tolist() == [[2, 0, 1], [0, 2, 1]]
    assert [lamp.target_side(Base, places, i) for i in range(2)] == ["right", "right"]
    assert ShellGameColorLampTask().final_places(Base, 2).tolist() == [[0, 1, 2]] * 2  # MIKASA fixes the colours
