"""MIKASA GatherAndRecall 1/3/5/7/9: the flash read from pixels, the controller's view, the prompt contract, the gather-and-press
expert, the task in the memory loop. Development seeds (5000+) only."""

import numpy as np
import pytest
import torch

from mikasa_support import MIKASA_MISSING, leaked_keys

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.memory.schema import MemoryType  # noqa: E402
from sb3_memret.memory.seeding import SeedingConfig  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt, parse_prompt  # noqa: E402
from sb3_memret.evaluation.rollout import evaluate_task_condition  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.core.carry_expert import GRIP_CLOSED  # noqa: E402
from sb3_memret.tasks.mikasa.core.cue_task import DEV_SEED  # noqa: E402
from sb3_memret.tasks.mikasa.gather_and_recall.task import (  # noqa: E402
    FLASH_COLOURS,
    INSTRUCTION,
    PROMPT_TEMPLATE,
    VARIANTS,
    GatherAndRecallTask,
)
from sb3_memret.tasks.mikasa.gather_and_recall.expert import WIDE_RING_CUBES, GatherGains, place_targets  # noqa: E402
from sb3_memret.tasks.mikasa.core.lamp_perception import read_lit_colour  # noqa: E402

TASK = "GatherAndRecall1-VLA-v0"
FORBIDDEN = ("oracle", "flash", "lamp", "pressed", "on_disc", "goal")


@pytest.fixture(scope="module")
def task():
    return GatherAndRecallTask()


@pytest.fixture(scope="module")
def rgb_env(task):
    env = task.make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    yield env
    env.close()


def _prompt(colour):
    return build_prompt(INSTRUCTION, [] if colour is None else [f"the flash was {colour}."], PROMPT_TEMPLATE)


def _play(env, expert, seed, colour, on_step=None, steps=200):
    """One episode with the expert prompted with ``colour``'s fact (None: none); MIKASA's success once."""
    obs, info = env.reset(seed=seed)
    prompt = _prompt(colour)
    expert.reset([seed])
    success, chunk = False, None
    for step in range(steps):
        if step % 4 == 0:
            chunk = expert.act(obs, [prompt])[0]
        obs, _, terminated, truncated, info = env.step(torch.from_numpy(chunk[step % 4][None]).float())
        success |= bool(info["success"][0])
        if on_step is not None:
            on_step(obs, info)
        if bool(terminated[0]) or bool(truncated[0]):
            break
    return success


def test_the_instruction_is_mikasas(rgb_env):
    stated = rgb_env.unwrapped.LANGUAGE_INSTRUCTION.lower().replace(". ", "; ")
    assert stated == INSTRUCTION


def test_read_flash_needs_a_lit_bulb(rgb_env):
    obs, _ = rgb_env.reset(seed=DEV_SEED)
    rgb = as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0]
    assert read_lit_colour(rgb) is None  # the lamp is white, the red cube and the caps are not lit
    for index, colour in enumerate(FLASH_COLOURS):
        lit = rgb.copy()
        lit[100:110, 80:90] = 3
        lit[100:110, 80:90, index] = 255
        assert read_lit_colour(lit) == colour
    mixed = rgb.copy()
    mixed[100:110, 80:90] = (255, 3, 3)
    mixed[100:110, 85:90] = (3, 3, 255)
    assert read_lit_colour(mixed) is None
    with pytest.raises(ValueError, match="one \\(H, W, 3\\) frame"):
        read_lit_colour(rgb[None])


def test_three_cubes_are_gathered_and_the_flash_read_among_them():
    """Every frame of a GatherAndRecall3 episode read against MIKASA's lamp state: the flash, whenever it is lit,
    and nothing else (the green and blue cubes neither); the expert places all three cubes and presses its button."""
    task = make_task("GatherAndRecall3-VLA-v0")
    env = task.make_env(obs_mode="rgb", render_backend="cpu", sim_backend="cpu")
    frames = {"flash": 0, "right": 0, "other": 0, "placed": 0}

    def check(obs, info):
        read = read_lit_colour(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0])
        frames["placed"] = int(info["n_on_disc"][0])
        if bool(info["flash_active"][0]):
            frames["flash"] += 1
            frames["right"] += read == FLASH_COLOURS[int(info["flash_color"][0])]
        else:
            frames["other"] += read is not None

    try:
        env.reset(seed=DEV_SEED + 7)
        truth = FLASH_COLOURS[int(env.unwrapped.flash_color[0])]
        assert _play(env, task.expert(), DEV_SEED + 7, truth, check, steps=task.max_control_steps)
        assert frames["placed"] == 3 and frames["flash"] >= 8 and frames["right"] == frames["flash"], frames
        assert frames["other"] == 0, frames
    finally:
        env.close()


def test_wrapper_exposes_only_the_controllers_view(task):
    env = task.make_env(obs_mode="state_dict", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    try:
        raw = env.unwrapped.get_obs()
        assert leaked_keys(raw, FORBIDDEN)  # the raw state holds the answer ...
        obs, _ = env.reset(seed=DEV_SEED)
        assert not leaked_keys(obs, FORBIDDEN)  # ... the controller's view does not
        assert set(obs["extra"]) == {"tcp_pose", "button_positions", "button_visible", "cube_positions",
                                     "disc_position"}
        assert obs["extra"]["cube_positions"].shape == (1, 1, 3)
        buttons = obs["extra"]["button_positions"][0].numpy()
        assert np.allclose(np.diff(buttons[:, 1]), 0.14, atol=1e-4)  # red, green, blue, 14 cm apart to the left
        assert np.allclose(obs["extra"]["disc_position"][0, 1].numpy() - buttons[1, 1], 0, atol=1e-4)
    finally:
        env.close()


def test_prompts_parse_with_the_flash_fact():
    for colour in FLASH_COLOURS:
        (fact,) = parse_prompt(_prompt(colour), PROMPT_TEMPLATE).facts
        assert dict(fact.fields) == {"entity": "flash", "colour": colour}
    with pytest.raises(ValueError, match="matches no trained template"):
        parse_prompt(f"{INSTRUCTION} the cube started at the left.", PROMPT_TEMPLATE)


def test_task_contract(rgb_env, task):
    assert make_task(TASK).name == TASK and task.perceives_every_step and task.max_control_steps == 200
    assert task.development_seeds(2) == [DEV_SEED, DEV_SEED + 1]
    with pytest.raises(ValueError, match="GatherAndRecall2-VLA-v0.*GatherAndRecall1-VLA-v0"):
        GatherAndRecallTask("GatherAndRecall2-VLA-v0")
    obs, info = rgb_env.reset(seed=DEV_SEED)
    (frame,) = task.frames(rgb_env, obs, info, reset=True)
    episode = task.episode(frame)
    colour = episode.group
    assert colour == FLASH_COLOURS[int(rgb_env.unwrapped.flash_color[0])]
    assert episode.true_facts == (((MemoryType.OTHER, "flash", "was"), colour),)
    assert task.oracle_facts(episode) == [f"the flash was {colour}."]
    (wrong,) = task.wrong_facts(episode)
    assert wrong.startswith("the flash was ") and colour not in wrong
    for fact in task.oracle_facts(episode) + task.wrong_facts(episode):
        parse_prompt(f"{task.instruction(episode)} {fact}", task.prompt_template)
    decoys = task.seed_memories(frame, episode, np.random.default_rng(0), SeedingConfig())
    assert len(decoys) == SeedingConfig().location_decoys
    for entry in decoys:
        assert entry.entity != "flash" and entry.value in FLASH_COLOURS
        assert entry.text == f"the {entry.entity} was {entry.value}."
        parse_prompt(f"{INSTRUCTION} {entry.text}", PROMPT_TEMPLATE)
    names = task.demo_features(with_images=False)["observation.state"]["names"]
    assert "button_green_x" in names and names[-6:] == ["cube_x", "cube_y", "cube_z", "disc_x", "disc_y", "disc_z"]
    assert task.demo_frame(obs, with_images=False)["observation.state"].shape == (len(names),)


@pytest.mark.parametrize("env_id", sorted(VARIANTS))
def test_every_variant_is_registered_with_mikasas_length(env_id):
    from sb3_memret.benchmark.manifest import select_tasks

    task = make_task(env_id)
    n_cubes, steps = VARIANTS[env_id]
    assert task.n_cubes == n_cubes == int(env_id.removeprefix("GatherAndRecall").split("-")[0])
    (row,) = select_tasks(env_ids=[env_id])
    assert task.max_control_steps == steps == row.max_episode_steps
    names = task.demo_features(with_images=False)["observation.state"]["names"]
    assert sum(name.endswith("_x") and name.startswith("cube") for name in names) == n_cubes


def test_place_targets_keep_cubes_apart_and_on_the_disc():
    disc = np.array([0.04, 0.14, 0.003])
    assert np.allclose(place_targets(disc, 1, 0.075), [disc[:2]])
    gains = GatherGains()
    for n in (3, 5, 7, 9):
        radius = gains.ring_radius if n < WIDE_RING_CUBES else gains.wide_ring_radius
        targets = place_targets(disc, n, radius, farthest=gains.ring_radius)
        assert targets.shape == (n, 2)
        off_centre = np.linalg.norm(targets - disc[:2], axis=1)
        centred = int(n > 5)  # past five, the first cube goes to the centre, the rest on the ring
        assert np.allclose(off_centre[:centred], 0.0) and (off_centre[centred:] >= gains.ring_radius - 1e-9).all()
        assert np.allclose(np.sort(off_centre[centred:])[1:], radius)  # only the place farthest from the arm comes in
        assert (targets[:, 0] - disc[0]).max() <= gains.ring_radius + 1e-9
        assert off_centre.max() + gains.over_disc <= gains.on_disc_radius + 1e-9 < 0.10  # MIKASA: on within 10 cm
        # the cubes stand square to the table: the larger of the x and y offsets parts two of them
        apart = np.abs(targets[:, None] - targets[None]).max(axis=2)[~np.eye(n, dtype=bool)]
        assert apart.min() > 0.059  # 4 cm cubes at least 1.9 cm apart (7.5 cm out, eight on the ring were 1.3 cm)
    with pytest.raises(ValueError, match="at least 1"):
        place_targets(disc, 0, 0.075)


def test_expert_places_the_cubes_in_order_then_presses():
    """Three cubes: the first unplaced one is grasped, a held one is carried to its own place above the placed
    ones, and the button is pressed only once all three rest on the disc."""
    expert = make_task("GatherAndRecall3-VLA-v0").expert()
    expert.reset([1])
    disc = np.array([0.04, 0.14, 0.003])
    places = place_targets(disc, 3, expert.gather.ring_radius)
    buttons = np.array([[[-0.18, 0.0, 0.015], [-0.18, 0.14, 0.015], [-0.18, 0.28, 0.015]]])

    def goal(tcp, cubes, gap=0.08):
        return expert._goal(np.asarray(tcp, float), np.asarray(cubes, float), gap, disc, buttons[0, 2])

    start = [[-0.04, -0.35, 0.02], [-0.04, -0.26, 0.02], [-0.04, -0.17, 0.02]]
    first_placed = [[*places[0], 0.026], *start[1:]]
    aim = goal([0.0, 0.0, 0.2], first_placed)
    assert aim.mode == "grasp" and np.allclose(aim.point, start[1])  # the first one not yet on the disc
    held = goal([-0.04, -0.26, 0.03], [first_placed[0], [-0.04, -0.26, 0.03], start[2]], gap=0.04)
    assert held.mode == "carry" and np.allclose(held.point[:2], places[1] + (0.0, 0.0), atol=0.011)
    assert held.height >= 0.10 and held.point[2] >= 0.10  # over the placed cube's top (4.6 cm)
    beside = goal([*places[0], 0.05], [[*places[0], 0.026], *start[1:]])
    assert beside.mode == "rise"  # open fingers never sweep sideways past a placed cube
    all_placed = [[*p, 0.026] for p in places]
    press = goal([0.0, 0.0, 0.2], all_placed)
    assert press.mode == "press" and np.allclose(press.point[:2], buttons[0, 2, :2])
    nudged = [all_placed[0], all_placed[1], [disc[0] + 0.12, disc[1], 0.026]]  # pushed off the disc
    assert goal([0.0, 0.0, 0.2], nudged).mode == "grasp"


def test_a_hand_stopped_just_off_the_cube_comes_down_and_closes():
    """At rest 6 mm aside and 12 mm over the cube's centre (where GatherAndRecall7's development seed 5013 stood
    open for 600 steps), the grasp goes on: the hand moves down, and the fingers close once it is close."""
    from sb3_memret.tasks.mikasa.core.touch_expert import R_DOWN
    from sb3_memret.tasks.mikasa.gather_and_recall.expert import GatherGoal

    expert = make_task("GatherAndRecall7-VLA-v0").expert()
    expert.reset([1])
    cube = np.array([-0.044, -0.255, 0.02])
    x, y, z, w = R_DOWN.as_quat()  # the hand pointing down, as a ManiSkill pose (x, y, z, qw, qx, qy, qz)
    tcp = np.array([*(cube + (-0.001, -0.006, 0.012)), w, x, y, z])
    chunk = expert._chunk(tcp, np.zeros(3), GatherGoal(cube.copy(), "grasp"))
    assert chunk[0, 2] < -0.05  # heading down, not braking in place
    assert chunk[-1, 6] == GRIP_CLOSED  # and closing within the chunk


def test_expert_heads_for_the_cube_then_for_the_named_button(task):
    expert = task.expert()
    expert.reset([1, 2])
    qpos = np.tile([0, 0, 0, -2.09, 0, 2.09, 0.79, 0.04, 0.04], (2, 1))
    buttons = np.tile([[-0.2, -0.02, 0.015], [-0.2, 0.12, 0.015], [-0.2, 0.26, 0.015]], (2, 1, 1))
    obs = {"agent": {"qpos": qpos, "qvel": np.zeros((2, 9))},
           "extra": {"tcp_pose": np.tile([0.0, 0.0, 0.2, 0, 1, 0, 0], (2, 1)),
                     "cube_positions": np.array([[[-0.06, -0.26, 0.02]], [[-0.06, -0.26, 0.02]]]),
                     "disc_position": np.tile([0.02, 0.12, 0.003], (2, 1)),
                     "button_positions": buttons, "button_visible": np.ones((2, 3), bool)}}
    chunks = expert.act(obs, [_prompt("blue"), _prompt(None)])
    assert chunks.shape == (2, 8, 7)
    assert np.all(chunks[:, 0, 1] < 0) and np.all(chunks[:, 0, 6] == 1.0)  # toward the cube, gripper open
    # the cube resting on the disc, the hand above it: to the button the prompt names, else the red one
    placed = {**obs, "extra": {**obs["extra"], "tcp_pose": np.tile([0.02, 0.12, 0.15, 0, 1, 0, 0], (2, 1)),
                               "cube_positions": np.tile([0.02, 0.12, 0.026], (2, 1, 1))}}
    chunks = expert.act(placed, [_prompt("blue"), _prompt(None)])
    assert chunks[0, 0, 1] > 0.3 and chunks[1, 0, 1] < -0.3 and np.all(chunks[:, 0, 0] < 0)
    assert np.all(chunks[:, :, 6] == -1.0)  # pressing with the fingers closed


def test_expert_presses_the_true_colour_only(task):
    env = task.make_env(obs_mode="state_dict", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    try:
        expert = task.expert()
        expert.check_env(env)
        seed = DEV_SEED + 2
        env.reset(seed=seed)
        truth = FLASH_COLOURS[int(env.unwrapped.flash_color[0])]
        other = FLASH_COLOURS[(FLASH_COLOURS.index(truth) + 1) % 3]
        assert _play(env, expert, seed, truth)
        assert not _play(env, expert, seed, other)
    finally:
        env.close()


def test_the_written_fact_reaches_the_expert():
    """``rollout --condition written``: the writer reads the flash from the camera and the expert presses its button."""
    results = evaluate_task_condition(make_task(TASK).expert(), "written", TASK, episodes=2, seed=DEV_SEED + 3,
                                      held_out=None)
    assert [r.success for r in results] == [True, True] and all(r.steps < 100 for r in results)


def test_the_flash_fact_is_written_and_retrieved(encoder):
    """Recall with the true slot on one episode: the fact enters the bank once the lamp has flashed, names the
    episode's colour, and the expert succeeds through it."""
    from sb3_memret.envs.vec_env import make_recall_vec_env

    venv = make_recall_vec_env(1, {"task": TASK, "controller": "scripted", "encoder": encoder, "replan_every": 4,
                                   "capacity": 6, "location_decoys": 5, "render_backend": "cpu"}, seed=0)
    try:
        venv.set_task_seeds([[DEV_SEED + 5]])
        venv.reset()
        memory = venv.venv.memories[0]
        colour = memory.truth.group
        fact = f"the flash was {colour}."
        assert fact not in [e.text for e in memory.bank.entries]  # not before the lamp has flashed
        done, success, written = False, False, False
        while not done:
            slot = memory.true_slot() if written else 0
            _, _, dones, infos = venv.step(np.array([[slot]]))
            done, success = bool(dones[0]), bool(infos[0]["success"])
            written = written or fact in [e.text for e in memory.bank.entries]
        assert written and success and infos[0]["group"] == colour
    finally:
        venv.close()
