"""MIKASA BatteriesChecker: the checklist's wording and parse, the writer's readers on rendered frames, the conditions'
facts, the zoo sections, and real-sim episodes where the expert completes check-confirm cycles (Easy and Hard).
Development seeds (5000+) only."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controllers.prompts import build_prompt, parse_prompt  # noqa: E402
from sb3_memret.tasks import check_task_name, make_task, task_names  # noqa: E402
from sb3_memret.tasks.base import EnvFrame  # noqa: E402
from sb3_memret.memory.schema import MemoryEntry  # noqa: E402
from sb3_memret.tasks.mikasa.batteries_checker.checklist import (  # noqa: E402
    CHECK_ENTITY, CHECK_RELATION, checklist_fact, checklist_value, parse_checklist, stated_checklist,
)
from sb3_memret.tasks.mikasa.batteries_checker.task import (  # noqa: E402
    EASY_INSTRUCTION, HARD_INSTRUCTION, PROMPT_TEMPLATE, VARIANTS,
)
from sb3_memret.tasks.mikasa.batteries_checker.writer import (  # noqa: E402
    CheckPercept, ChecklistWriter, lamp_lit, read_batteries, read_button,
)
from sb3_memret.tasks.mikasa.core.cue_task import DEV_SEED  # noqa: E402

EASY = "BatteriesCheckerEasy-3-VLA-v0"


def test_the_ids_are_mikasas_with_their_lengths():
    import gymnasium as gym
    from mikasa_robo_suite.vla.memory_envs import batteries_checker_hard_vla as hard

    assert set(VARIANTS) <= set(task_names())
    for name, variant in VARIANTS.items():
        assert variant.steps == gym.spec(name).max_episode_steps
        check_task_name(name)
        task = make_task(name)
        assert task.max_control_steps == variant.steps and task.replan_every == 4 and task.perceives_every_step
    assert HARD_INSTRUCTION == hard.BatteriesCheckerVLABaseEnv.LANGUAGE_INSTRUCTION.lower()
    assert EASY_INSTRUCTION.startswith("find all working batteries by inserting")
    from sb3_memret.tasks.mikasa.batteries_checker.task import BatteriesCheckerTask

    with pytest.raises(ValueError, match="unknown BatteriesChecker task"):
        BatteriesCheckerTask("BatteriesCheckerEasy-9-VLA-v0")


def test_one_fact_carries_the_whole_checklist_and_parses_back():
    checks = {3: True, 1: False}
    assert checklist_value(checks) == "slot 1 dead and slot 3 working"
    fact = checklist_fact(checks)
    assert fact == "the battery check found slot 1 dead and slot 3 working."
    parsed = parse_prompt(build_prompt(EASY_INSTRUCTION, [fact], PROMPT_TEMPLATE), PROMPT_TEMPLATE)
    assert stated_checklist(parsed) == {1: False, 3: True} == parse_checklist(checklist_value(checks))
    decoy = parse_prompt(f"{EASY_INSTRUCTION} the fuse check found slot 2 working.", PROMPT_TEMPLATE)
    assert stated_checklist(decoy) == {2: True}  # a decoy misleads the expert as a wrong fact would
    assert stated_checklist(parse_prompt(EASY_INSTRUCTION, PROMPT_TEMPLATE)) == {}
    with pytest.raises(ValueError, match="empty checklist"):
        checklist_value({})
    with pytest.raises(ValueError, match="slots are whole numbers from 1"):
        checklist_value({0: True})
    with pytest.raises(ValueError, match="not a checklist"):
        parse_checklist("slot one dead")
    with pytest.raises(ValueError, match="matches no trained template"):
        build_prompt(EASY_INSTRUCTION, ["the battery check found slot 1 empty."], PROMPT_TEMPLATE)


def test_the_conditions_word_mikasas_counters_at_each_decision():
    task = make_task(EASY)
    frame = EnvFrame({}, {"checked": (), "working": (2,)}, None, False)
    episode = task.episode(frame)
    assert episode.group == "2"
    assert task.facts_now("oracle", episode, frame, 0) == task.oracle_facts(episode) == []
    assert task.facts_now("wrong", episode, frame, 0) == task.wrong_facts(episode) == [
        "the battery check found slot 1 working and slot 2 dead and slot 3 working."]
    later = EnvFrame({}, {"checked": (1, 2), "working": (2,)}, None, False)
    assert task.facts_now("oracle", episode, later, 90) == ["the battery check found slot 1 dead and slot 2 working."]
    assert task.facts_now("wrong", episode, later, 90) == ["the battery check found slot 3 working."]


def test_the_memory_needed_is_the_checklist_right_so_far():
    """The checklist grows as the robot works: a partial one whose every check is right is the memory the
    controller needs (what retrieval is scored by), a wrong check or another thing's list is not."""
    task = make_task(EASY)
    episode = task.episode(EnvFrame({}, {"checked": (), "working": (2,)}, None, False))
    key = task.cue_key

    def entry(value, entity=CHECK_ENTITY):
        return MemoryEntry.create(key[0], entity, CHECK_RELATION, value, 0)

    assert entry("slot 1 dead").key == key
    for value in ("slot 1 dead", "slot 2 working", "slot 1 dead and slot 3 dead",
                  "slot 1 dead and slot 2 working and slot 3 dead"):
        assert episode.is_true(entry(value)), value
    for value in ("slot 1 working", "slot 1 dead and slot 2 dead", "slot 4 dead"):
        assert not episode.is_true(entry(value)), value
    assert not episode.is_true(entry("slot 1 dead", entity="fuse check"))


def test_every_variant_has_a_zoo_section_naming_it():
    """Every section names its task; the runnable ones parse (a refused task's is refused with the task's reason)."""
    from pathlib import Path

    import yaml

    from sb3_memret.training.config import load_config

    zoo = Path(__file__).resolve().parents[1] / "zoo_configs" / "memret_ppo_mikasa.yml"
    sections = yaml.safe_load(zoo.read_text())
    for name, variant in VARIANTS.items():
        assert sections[name]["env_kwargs"]["task"] == name and sections[name]["env_kwargs"]["k"] == 1
        if not variant.hard:
            assert load_config(zoo, name).env_kwargs["task"] == name


def _percept(tcp, gap, lit=False, button=(0.0, 0.25)):
    return CheckPercept(tcp, gap, lit, ((0.01, -0.08), (-0.04, -0.08), (-0.09, -0.08)), button)


def test_the_writer_follows_pick_test_and_press_and_ignores_a_press_without_a_test():
    writer = ChecklistWriter(3, hard=False)
    above_button, on_button = (0.0, 0.25, 0.2), (0.0, 0.25, 0.075)
    steps = [_percept(above_button, 0.04), _percept(on_button, 0.0), _percept(above_button, 0.0),  # a bare press
             _percept((-0.04, -0.08, 0.04), 0.04), _percept((-0.04, -0.08, 0.04), 0.017),  # battery 2 picked
             _percept((0.16, 0.02, 0.07), 0.017), _percept((0.16, 0.02, 0.07), 0.04, lit=True),  # tested: lit
             _percept(above_button, 0.0), _percept(on_button, 0.0)]  # confirmed
    frame = EnvFrame({}, None, None, False, percepts=steps)
    assert writer.read(frame) == [(8, {("checked", "battery check"): "slot 2 working"})]


@pytest.fixture(scope="module")
def played():
    """One expert episode of Easy-3 at a development seed under the written condition, with every base-camera
    frame and MIKASA's lamp and counters at each step."""
    from sb3_memret.common.obs_trees import to_numpy

    task = make_task(EASY)
    env = task.make_env(**task.env_kwargs(False, "cpu"))
    expert = task.expert()
    obs, info = env.reset(seed=DEV_SEED)
    expert.reset([DEV_SEED])
    writer, frames, lit, checked, success, facts = task.writer(), [], [], [], False, []
    frame = task.frames(env, obs, info, reset=True)[0]
    frame.percepts = [task.perceive(env, obs)]

    def written(frame):
        return [checklist_fact(parse_checklist(value)) for _, predicates in writer.read(frame)
                for value in predicates.values()]

    facts += written(frame)
    for _ in range(260):
        prompt = build_prompt(task.instruction_text, facts[-1:], task.prompt_template)
        chunk = expert.act(obs, [prompt])[0][:task.replan_every]
        percepts = []
        for action in chunk:
            obs, _, terminated, truncated, info = env.step(action)
            frames.append(to_numpy(obs)["sensor_data"]["base_camera"]["rgb"][0])
            lit.append(bool(env.unwrapped.lamp_bulb_on.pose.p[0, 2] < 10))
            checked.append(int(info["checked_count"][0]))
            percepts.append(task.perceive(env, obs))
            success |= bool(info["success"][0])
        frame = task.frames(env, obs, info)[0]
        frame.steps, frame.percepts = len(chunk), percepts
        facts += written(frame)
        if success or bool(terminated) or bool(truncated):
            break
    base = env.unwrapped
    truth = {"slots": base.tray_slot_positions[0, :3, :2].numpy(), "button": base.button_xy[0].numpy(),
             "working": tuple(int(s) + 1 for s in np.flatnonzero(base.working_mask[0, :3].numpy()))}
    env.close()
    return {"frames": frames, "lit": lit, "checked": checked, "success": success, "facts": facts, **truth}


@pytest.mark.slow
def test_the_readers_see_the_slots_the_button_and_the_lamp_as_mikasa_has_them(played):
    first = played["frames"][0]
    assert np.abs(read_batteries(first) - played["slots"]).max() < 0.006
    assert np.linalg.norm(read_button(first) - played["button"]) < 0.005
    assert [lamp_lit(rgb) for rgb in played["frames"]] == played["lit"] and any(played["lit"])


@pytest.mark.slow
def test_the_expert_completes_check_confirm_cycles_on_the_writers_checklist(played):
    assert played["success"] and played["checked"][-1] == 3  # every cycle confirmed, on the written facts alone
    final = parse_checklist(played["facts"][-1].removeprefix("the battery check found ").removesuffix("."))
    assert final == {slot: slot in played["working"] for slot in (1, 2, 3)}



@pytest.mark.slow
@pytest.mark.parametrize("env_id", ["BatteriesCheckerEasy-6-VLA-v0", "BatteriesCheckerHard-3-VLA-v0"])
def test_the_expert_checks_every_battery_without_disturbing_the_others(env_id):
    """Easy-6's tray has two rows 5 cm apart: the fingers come down on one battery and lift it without moving any
    other; Hard's expert takes each battery back out of the socket, sets it home and leaves it there (MIKASA counts
    success only with every checked battery home). Through the benchmark's harness, the oracle condition, at a
    development seed."""
    import torch

    from sb3_memret.benchmark import harness
    from sb3_memret.benchmark.agent import MemoryAgent
    from sb3_memret.controller_specs import make_controller

    env, task = harness.make_env(env_id), make_task(env_id)
    expert, n = make_controller("scripted", task), task.variant.batteries
    base, step, moved, last = env.unwrapped, env.step, np.zeros(n), []

    def spied_step(action):
        out = step(action)
        now = torch.stack([b.pose.p[0] for b in base.batteries[:n]]).numpy()
        if last:  # how far each battery went this step, counted unless it is the one the expert is checking
            others = [k for k in range(n) if k != expert.cycles[0].battery]
            moved[others] += np.linalg.norm(now - last[-1], axis=1)[others]
        last[:] = [now]
        return out

    env.step = spied_step
    agent = MemoryAgent(task, expert, "oracle", None)
    agent.bind(env)
    agent.begin(0)
    result = harness.play_episode(env, agent, DEV_SEED)
    env.close()
    assert result.success_once and int(base.checked_count[0]) == task.variant.batteries
    assert moved.max() < 0.003, f"batteries moved (m) while another was checked: {np.round(moved, 4)}"


def test_other_checks_are_of_the_moment_and_the_batteries_checklist_of_the_episode():
    """The stores comparison on Easy-6 (``memret_ppo_timescales_batteries*.yml``): event decoys worded as the
    reset's, passing the prompt check; the checklist in the episode's store, every other check in the moment's; the
    stores and the one bank hold the same slots."""
    from pathlib import Path

    from sb3_memret.memory.schema import MemoryType
    from sb3_memret.memory.seeding import SeedingConfig
    from sb3_memret.training.config import load_config

    env_id = "BatteriesCheckerEasy-6-VLA-v0"
    task, seeding, rng = make_task(env_id), SeedingConfig(), np.random.default_rng(0)
    events = [task.event_decoy(rng, 40 + 8 * i, seeding) for i in range(30)]
    assert [e.timestamp for e in events] == [40 + 8 * i for i in range(30)]
    decoys = task.seed_memories(None, None, rng, SeedingConfig(location_decoys=5))
    things = {e.entity.removesuffix(" check") for e in events + decoys}
    assert things <= set(seeding.vocabulary) - {"battery"} and "battery" in seeding.vocabulary  # never the fact's own
    with pytest.raises(ValueError, match="other than the battery"):
        task.seed_memories(None, None, rng, SeedingConfig(location_decoys=2, vocabulary=("battery", "key")))
    assert all(set(parse_checklist(e.value)) <= set(range(1, 7)) for e in events) and len({e.text for e in events}) > 10
    prompt = build_prompt(EASY_INSTRUCTION, [events[0].text], PROMPT_TEMPLATE)
    assert stated_checklist(parse_prompt(prompt, PROMPT_TEMPLATE)) == parse_checklist(events[0].value)
    checklist = MemoryEntry.create(MemoryType.OTHER, CHECK_ENTITY, CHECK_RELATION, "slot 1 dead", 12)
    assert {task.timescale(e) for e in events + decoys} == {"now"} and task.timescale(checklist) == "episode"
    zoo = Path(__file__).resolve().parents[1] / "zoo_configs"
    stores = load_config(zoo / "memret_ppo_timescales_batteries.yml", env_id).env_kwargs
    one_bank = load_config(zoo / "memret_ppo_timescales_batteries_one_bank.yml", env_id).env_kwargs
    assert sum(store["capacity"] for store in stores["stores"]) == one_bank["capacity"]
    assert {k: v for k, v in stores.items() if k != "stores"} == {k: v for k, v in one_bank.items() if k != "capacity"}


def test_the_pick_comes_down_its_funnel_and_rises_straight_only_from_below_it():
    """On its way down a battery's funnel, far sideways and below the clear height, the hand keeps coming down the
    funnel (turning back up to the clear height there swung it onto the battery's top); from below the funnel (by
    the button or the socket) it rises straight onto the funnel first; other goals rise to the clear height."""
    from sb3_memret.tasks.mikasa.batteries_checker.expert import GRIP_PICK, BatteryCheckController, CheckGoal

    expert = BatteryCheckController(PROMPT_TEMPLATE, hard=False)
    g, c = expert.gains, expert.check
    grasp = np.array([-0.13, -0.056, 0.035])
    pick = CheckGoal(grasp, GRIP_PICK, funnel=True)
    in_funnel = grasp + (0.011, 0.038, g.funnel_slope * 0.04 + 0.01)  # 4 cm sideways, over the funnel, under 11 cm
    assert in_funnel[2] < c.clear_height - 0.02
    waypoint = expert._waypoint(in_funnel, pick)
    assert np.allclose(waypoint[:2], grasp[:2]) and waypoint[2] < in_funnel[2]
    below = grasp + (0.0, 0.2, 0.0)  # 20 cm sideways at the grasp height: straight up onto the funnel's top
    assert np.allclose(expert._waypoint(below, pick), [*below[:2], grasp[2] + g.hover_height])
    carry = CheckGoal(grasp + (0.0, 0.2, 0.0), GRIP_PICK)
    assert np.allclose(expert._waypoint(in_funnel, carry), [*in_funnel[:2], c.clear_height])
    look = CheckGoal(grasp + (0.0, 0.2, 0.3), GRIP_PICK)  # a goal high up: straight up to the clear height only
    assert np.allclose(expert._waypoint(in_funnel, look), [*in_funnel[:2], c.clear_height])
    near = grasp + (0.01, 0.0, 0.0)  # within reach sideways: straight down the funnel, no rising
    assert np.allclose(expert._waypoint(near, pick), [*grasp[:2], grasp[2] + g.funnel_slope * 0.01])


def test_two_tops_that_touch_in_the_picture_are_split_when_the_count_is_known():
    """Development seed 5014 (Easy-3): two tops of one row show as one blob of 12 pixels; told three batteries stand,
    the reader splits it across its long axis, and a blob one top can make is never split."""
    frame = np.zeros((128, 128, 3), np.uint8)
    green = [(64, 56), (64, 57), (65, 56), (65, 57), (66, 56), (66, 57), (67, 56), (68, 55), (68, 56), (69, 56),
             (69, 57), (70, 56), (72, 55), (72, 56), (73, 55), (73, 56), (74, 56)]  # its first frame's green pixels
    for r, c in green:
        frame[r, c] = (40, 200, 60)
    assert len(read_batteries(frame)) == 2
    three = read_batteries(frame, 3)
    assert len(three) == 3 and np.all(np.diff(three[:, 0]) < -0.03)  # one row, 5 cm apart, from the camera's side
    assert np.ptp(three[:, 1]) < 0.01
    assert len(read_batteries(frame, 4)) == 3  # no blob left that two tops could make


def test_near_the_arms_reach_each_action_asks_for_a_pose_within_reach():
    """Beyond ``far_x`` (the socket's side) the chunk's translations are at most ``far_action``: a full action's IK
    target there is out of reach and the arm drops it; elsewhere the chunk runs at full speed."""
    from sb3_memret.tasks.mikasa.batteries_checker.expert import GRIP_PICK, BatteryCheckController, CheckGoal

    expert = BatteryCheckController(PROMPT_TEMPLATE, hard=False)
    c, down = expert.check, [0.0, 1.0, 0.0, 0.0]  # (qw, qx, qy, qz): pointing down
    for x, limit in ((c.far_x + 0.04, c.far_action), (c.far_x - 0.1, 1.0)):
        tcp = np.array([x, 0.0, 0.15, *down])
        chunk = expert._chunk(tcp, np.array([0.0, 0.0, 0.02]), CheckGoal(tcp[:3] + (0.0, 0.0, -0.1), GRIP_PICK))
        norms = np.linalg.norm(chunk[:, :3], axis=1)
        assert norms.max() <= limit + 1e-9 and (x < c.far_x) == (norms.max() > c.far_action)


def test_over_a_socket_at_the_arms_reach_it_lets_go_from_as_low_as_it_came():
    """Held still over the socket, 5.5 cm up: within reach it lowers on; at its reach (the hand at ``max_x``, the
    socket 19 cm out) it can come no lower and lets go from there."""
    from sb3_memret.tasks.mikasa.batteries_checker.expert import GRIP_PICK, BatteryCheckController, Cycle

    expert = BatteryCheckController(PROMPT_TEMPLATE, hard=False)
    c, reach = expert.check, expert.gains.max_x
    slots = np.array([[-0.05, -0.1, 0.03], [-0.10, -0.1, 0.03], [-0.15, -0.1, 0.03]])
    cap = np.array([-0.1, 0.14, 0.058])
    for socket_x, lets_go in ((reach - 0.04, False), (reach, True)):
        socket = np.array([socket_x, -0.05, 0.03])
        battery = socket + (0.0, 0.0, 0.055)
        hand = battery + (0.0, 0.0, 0.006)
        cycle = Cycle(battery=0, stage="insert", seen=battery.copy())  # held, and as it was at the last decision
        batteries = np.vstack([battery, slots[1:]])
        goal = expert._goal(cycle, hand, 0.016, batteries, slots, socket, cap)
        assert (goal.grip == GRIP_PICK) == lets_go
        if not lets_go:
            assert goal.point[2] < hand[2] and goal.point[2] > socket[2] + c.drop_above  # down a step
