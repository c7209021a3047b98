"""MIKASA FindImposterColor/Shape/ShapeAndColor: the set reader, both fact wordings, the writer, the imposter expert."""

import json

import numpy as np
import pytest
import torch

from mikasa_support import MIKASA_MISSING, leaked_keys

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from click.testing import CliRunner  # noqa: E402

from sb3_memret.cli import main  # noqa: E402
from sb3_memret.memory.schema import MemoryEntry, MemoryType  # noqa: E402
from sb3_memret.memory.seeding import SeedingConfig  # noqa: E402
from sb3_memret.controllers.prompts import build_prompt, parse_prompt  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.base import EnvFrame  # noqa: E402
from sb3_memret.tasks.mikasa.find_imposter.task import (  # noqa: E402
    FindImposterColorTask,
    FindImposterShapeAndColorTask,
    FindImposterShapeTask,
    plural,
    set_phrase,
)
from sb3_memret.tasks.mikasa.find_imposter.perception import (  # noqa: E402
    CROP_HALF,
    TOP_SHADES,
    SeenObject,
    ShapeExemplars,
    object_crop,
    objects_in_view,
    split_in_two,
    task_exemplars,
)

FORBIDDEN = ("oracle", "task_cue", "goal_")


def _imposter(task, env, obs, info) -> str:
    """The episode's imposter (the simulator's truth, for scoring only)."""
    return task.episode(task.frames(env, obs, info, reset=True)[0]).group


def test_the_nine_tasks_are_registered_with_mikasas_objects():
    sizes = {"FindImposterColor3-VLA-v0": 3, "FindImposterColor9-VLA-v0": 9, "FindImposterShape5-VLA-v0": 5,
             "FindImposterShapeAndColor3x2-VLA-v0": 6, "FindImposterShapeAndColor5x3-VLA-v0": 15}
    for env_id, n in sizes.items():
        assert len(make_task(env_id).words) == n
    for family, ids in ((FindImposterColorTask, ("3", "5", "9")), (FindImposterShapeTask, ("3", "5", "9")),
                        (FindImposterShapeAndColorTask, ("3x2", "3x3", "5x3"))):
        for size in ids:
            task = make_task(f"{family.__name__.removesuffix('Task')}{size}-VLA-v0")
            assert type(task) is family and task.wording == "set"
    assert make_task("FindImposterShape9-VLA-v0").words[-3:] == ("pyramid", "t shape", "crescent")
    assert make_task("FindImposterShapeAndColor5x3-VLA-v0").max_control_steps == 40
    assert make_task("FindImposterShapeAndColor3x3-VLA-v0").max_control_steps == 25
    with pytest.raises(ValueError, match="unknown FindImposterColorTask env 'FindImposterColor4-VLA-v0'"):
        FindImposterColorTask("FindImposterColor4-VLA-v0")
    with pytest.raises(ValueError, match="unknown wording 'list'; expected one of \\['set', 'each'\\]"):
        FindImposterColorTask("FindImposterColor3-VLA-v0", wording="list")
    assert plural("key") == "keys" and plural("battery") == "batteries"
    assert set_phrase(["a", "b", "c"]) == "a and b and c"


@pytest.mark.parametrize("wording", ["set", "each"])
def test_both_wordings_parse_and_the_expert_reads_the_imposter_from_them(wording):
    cases = [(FindImposterColorTask("FindImposterColor3-VLA-v0", wording), "lime",
              {"set": ["the shown cubes were red and blue."],
               "each": ["the red cube was shown.", "the blue cube was shown."]}),
             (FindImposterShapeTask("FindImposterShape9-VLA-v0", wording), "t shape",
              {"set": ["the shown objects were a cube and a sphere and a cylinder and a cross and a torus and a "
                       "star and a pyramid and a crescent."], "each": None}),
             (FindImposterShapeAndColorTask("FindImposterShapeAndColor3x2-VLA-v0", wording), "red sphere",
              {"set": ["the shown objects were a red cube and a lime cube and a blue cube and a lime sphere and a blue "
                       "sphere."], "each": ["the red cube was shown.", "the lime cube was shown.",
                                            "the blue cube was shown.", "the lime sphere was shown.",
                                            "the blue sphere was shown."]})]
    for task, imposter, expected in cases:
        episode = task.episode(EnvFrame({}, {"imposter": imposter}, None, False))
        oracle, wrong = task.oracle_facts(episode), task.wrong_facts(episode)
        assert len(oracle) == (1 if wording == "set" else task.n_words - 1) and imposter not in " ".join(oracle)
        if expected[wording] is not None:
            assert oracle == expected[wording]
        expert = task.expert()
        for facts, meant in ((oracle, imposter), (wrong, task.words[(task.words.index(imposter) + 1) % task.n_words]),
                             ([], task.words[0])):
            parsed = parse_prompt(build_prompt(task.instruction(episode), facts, task.prompt_template),
                                  task.prompt_template)
            assert expert._chosen([parsed]) == [meant], (task.name, facts)
        decoys = task.seed_memories(EnvFrame({}, {}, None, False), episode, np.random.default_rng(0), SeedingConfig())
        assert len(decoys) == SeedingConfig().location_decoys
        for entry in decoys:
            parse_prompt(f"{task.instruction(episode)} {entry.text}", task.prompt_template)  # worded alike
            assert not episode.is_true(entry)
        true = [MemoryEntry.create(*key, value, 0) for key, value in episode.true_facts]
        assert [e.text for e in true] == oracle and all(episode.is_true(e) for e in true)


def test_the_writer_writes_the_first_set_it_sees_once_per_episode():
    task = FindImposterColorTask("FindImposterColor3-VLA-v0", "each")
    writer = task.writer()
    assert writer.relations == {"shown": (MemoryType.OTHER, "was")}
    reset = EnvFrame({}, {}, None, False, steps=0, percepts=[None])
    chunk = EnvFrame({}, {}, None, False, steps=3, percepts=[("red", "lime"), ("red", "blue"), None])
    assert writer.read(reset) == []
    assert writer.read(chunk) == [(1, {("shown", "red cube"): "shown", ("shown", "lime cube"): "shown"})]
    assert writer.read(chunk) == []  # written once: a later frame of N - 1 (an object behind the arm) changes nothing
    assert writer.read(EnvFrame({}, {}, None, False, steps=0, percepts=[("lime", "blue")])) == [
        (0, {("shown", "lime cube"): "shown", ("shown", "blue cube"): "shown"})]  # a new episode
    set_writer = FindImposterColorTask("FindImposterColor3-VLA-v0").writer()
    assert set_writer.relations == {"shown": (MemoryType.OTHER, "were")}
    assert set_writer.read(EnvFrame({}, {}, None, False, steps=0, percepts=[("blue", "red")])) == [
        (0, {("shown", "shown cubes"): "red and blue"})]


@pytest.mark.parametrize("env_id, seeds", [("FindImposterColor5-VLA-v0", (5000,)),
                                           ("FindImposterShape3-VLA-v0", (5001,)),
                                           ("FindImposterShape9-VLA-v0", (5002, 5006)),
                                           ("FindImposterShapeAndColor3x2-VLA-v0", (5000,))])
def test_reads_the_shown_set_in_the_cue_and_none_in_the_delay(env_id, seeds):
    task = make_task(env_id)
    env = task.make_env(obs_mode="rgb", sim_backend="cpu", robot_uids="panda")
    try:
        for seed in seeds:
            obs, info = env.reset(seed=seed)
            assert not leaked_keys(obs, FORBIDDEN)
            base, imposter = env.unwrapped, _imposter(task, env, obs, info)
            cue, hidden = int(base.cue_steps_per_env[0]), int(base.empty_steps_per_env[0])
            shown = tuple(w for w in task.words if w != imposter)
            for step in range(cue + hidden):  # the choice frames may show N - 1 apart (two merged): the writer
                assert task.perceive(env, obs) == (shown if step < cue else None), (seed, step)  # writes once
                obs, _, _, _, info = env.step(torch.zeros(1, 7))
            obs, _, _, _, info = env.step(torch.zeros(1, 7))
            assert bool(obs["extra"][f"{task.detector_key}_visible"].all())  # the choice: all N, the imposter too
    finally:
        env.close()


def _square(row: int, col: int, size: int = 4) -> np.ndarray:
    """A 128x128 frame of one blue square, its top rows a brighter shade, and its mask."""
    rgb = np.zeros((128, 128, 3), np.uint8)
    rgb[row:row + size, col:col + size, 2] = 148
    rgb[row:row + size // 2, col:col + size, 2] = 231
    return rgb, rgb.any(axis=-1)


def test_shape_exemplars_match_an_object_to_its_shape_seen_at_its_place(tmp_path):
    square, square_mask = _square(60, 40)
    wide, wide_mask = _square(60, 40, size=8)
    far, far_mask = _square(20, 100)
    centres, crops = zip(*(object_crop(rgb, mask) for rgb, mask in ((square, square_mask), (wide, wide_mask),
                                                                      (far, far_mask))))
    assert crops[0].shape == (2 * CROP_HALF + 1,) * 2 and crops[0].max() == 1.0 and crops[0].min() == 0.0
    exemplars = ShapeExemplars(np.array(centres, np.float32), np.array(crops), np.array(["cube", "slab", "slab"]))
    exemplars.save(tmp_path / "exemplars.npz")
    loaded = ShapeExemplars.load(tmp_path / "exemplars.npz")
    assert np.array_equal(loaded.shapes, exemplars.shapes) and np.allclose(loaded.crops, exemplars.crops, atol=1 / 255)

    shifted, shifted_mask = _square(61, 41)  # the square a pixel off: a cube still, at no cost
    seen = [SeenObject(shifted_mask, np.zeros(1), 0), SeenObject(wide_mask, np.zeros(1), 0)]
    cost = loaded.costs(shifted, seen[:1], ["cube", "slab"])
    assert cost[0, 0] < 0.01 < cost[0, 1]  # 0.01: the stored shades are rounded to 1/255
    assert loaded.costs(wide, seen[1:], ["cube", "slab"])[0].argmin() == 1
    with pytest.raises(ValueError, match="no exemplars of shapes \\['torus'\\]"):
        loaded.costs(shifted, seen[:1], ["cube", "torus"])
    with pytest.raises(FileNotFoundError, match="calibrate_imposter.py calibrate"):
        ShapeExemplars.load(tmp_path / "missing.npz")
    with pytest.raises(ValueError, match="as many centres"):
        ShapeExemplars(np.zeros((2, 2), np.float32), np.array(crops), np.array(["cube", "slab", "slab"]))


def test_every_shape_task_ships_exemplars_of_all_its_shapes():
    for env_id in ("FindImposterShape3-VLA-v0", "FindImposterShape5-VLA-v0", "FindImposterShape9-VLA-v0",
                   "FindImposterShapeAndColor3x2-VLA-v0", "FindImposterShapeAndColor3x3-VLA-v0",
                   "FindImposterShapeAndColor5x3-VLA-v0"):
        task = make_task(env_id)
        shapes = {task.candidate(w)[1] for w in task.words}
        assert task.reads_shapes and shapes == set(task_exemplars(env_id).shapes.tolist()), env_id


def test_two_touching_objects_are_cut_apart():
    blob = np.zeros((128, 128), bool)
    blob[60:64, 50:54] = blob[61:63, 54:56] = blob[60:64, 56:60] = True  # two squares joined by a bridge
    halves = sorted(split_in_two(blob), key=lambda h: np.argwhere(h)[:, 1].mean())
    assert halves[0].sum() + halves[1].sum() == blob.sum() and min(h.sum() for h in halves) >= 16
    assert np.argwhere(halves[0])[:, 1].max() <= 55 <= np.argwhere(halves[1])[:, 1].min()  # cut at the bridge
    assert split_in_two(np.pad(np.ones((2, 3), bool), 10)) is None  # halves smaller than an object


def test_with_counts_per_colour_the_colour_short_of_objects_is_cut_not_the_largest():
    """A near red object, large in the picture, and two far blue ones that touch: three objects expected. Cutting
    the largest group cuts the red one; with the counts per colour, the blue pair is cut apart."""
    frame = np.full((128, 128, 3), 120, dtype=np.uint8)
    frame[96:112, 40:56] = TOP_SHADES[0]  # red, near: 256 pixels
    frame[40:44, 70:74] = frame[41:43, 74:76] = frame[40:44, 76:80] = TOP_SHADES[2]  # blue, two joined
    def colours(objects):
        return sorted(int(np.argmin(o.top_distance)) for o in objects)

    assert colours(objects_in_view(frame, 3, 3)) == [0, 0, 2]
    by_colour = objects_in_view(frame, 3, 3, per_colour=[1, 0, 2])
    assert colours(by_colour) == [0, 2, 2] and min(o.mask.sum() for o in by_colour) >= 12
    with pytest.raises(ValueError, match="per_colour"):
        objects_in_view(frame, 3, 3, per_colour=[1, 2])


@pytest.mark.parametrize("env_id, wording", [("FindImposterColor3-VLA-v0", "set"),
                                             ("FindImposterShapeAndColor3x2-VLA-v0", "each"),
                                             ("FindImposterShapeAndColor5x3-VLA-v0", "set")])  # 5000, 5001: x > 0.18
def test_the_expert_touches_the_imposter_with_the_oracle_facts_and_not_with_the_wrong(env_id, wording):
    task = make_task(env_id)
    task = type(task)(env_id, wording)
    env = task.make_env(obs_mode="state_dict", sim_backend="cpu", robot_uids="panda")
    expert = task.expert()
    try:
        expert.check_env(env)
        for seed, condition in ((5000, "oracle"), (5001, "oracle"), (5002, "wrong")):
            obs, info = env.reset(seed=seed)
            episode = task.episode(EnvFrame({}, {"imposter": _imposter(task, env, obs, info)}, None, False))
            facts = task.oracle_facts(episode) if condition == "oracle" else task.wrong_facts(episode)
            prompt = build_prompt(task.instruction(episode), facts, task.prompt_template)
            expert.reset([seed])
            success = False
            for step in range(task.max_control_steps):
                if step % 4 == 0:
                    chunk = expert.act(obs, [prompt])[0]
                obs, _, _, _, info = env.step(torch.from_numpy(chunk[step % 4][None]).float())
                success |= bool(info["success"][0])
            assert success == (condition == "oracle"), (seed, condition)
    finally:
        env.close()


def test_the_expert_waits_until_every_object_is_in_sight():
    task = make_task("FindImposterColor3-VLA-v0")
    expert = task.expert()
    expert.reset([0, 1])
    obs = {
        "agent": {"qpos": np.tile([0, 0, 0, -2.09, 0, 2.09, 0.79, 0.04, 0.04], (2, 1)), "qvel": np.zeros((2, 9))},
        "extra": {"tcp_pose": np.tile([-0.07, 0, 0.32, 0, 1, 0, 0], (2, 1)),
                  "cube_positions": np.tile([[0.0, 0.2, 0.02], [0.0, -0.2, 0.02], [0.0, 0.0, 0.02]], (2, 1, 1)),
                  "cube_visible": np.array([[True, True, True], [True, False, True]])},
    }
    prompt = build_prompt(task.instruction_text, ["the shown cubes were red and blue."], task.prompt_template)
    chunks = expert.act(obs, [prompt, prompt])
    assert chunks[0, 0, 1] < -0.5  # all in sight: toward lime, at -y
    ready = expert.act({**obs, "extra": {**obs["extra"], "cube_visible": np.tile([True, False, True], (2, 1))}},
                       [prompt, prompt])
    assert np.allclose(ready[0], ready[1]) and abs(ready[0, 0, 1]) < 0.1  # the cue: to the ready pose, not to a cube


def test_rollout_written_reads_the_set_from_the_camera():
    result = CliRunner().invoke(main, ["rollout", "--task", "FindImposterColor3-VLA-v0", "--controller", "scripted",
                                       "--condition", "written", "--episodes", "1", "--seeds", "dev", "--seed", "5000",
                                       "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output.strip().splitlines()[-1])["success"]["overall"] == 1.0
