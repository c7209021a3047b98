"""Finetuning the learned controller: chunk targets stay inside their episode, datasets are checked, the
policy learns the expert's labels on a small budget, and the checkpoint loads as a controller."""

from __future__ import annotations

import json

import numpy as np
import torch
import pytest

from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers.learned import LearnedPolicyConfig
from sb3_memret.controllers.learned.modeling import pointer_ambiguity
from sb3_memret.controllers.observation import PROPRIO_NAMES, STATE_NAMES
from sb3_memret.physics.backends import TaskEnvInfo
from sb3_memret.tasks.drawer.prompts import INSTRUCTION, condition_prompt
from sb3_memret.tasks.drawer.drawer_cube import DEFAULT_ROBOT
from sb3_memret.tasks.drawer.robot import LIGHT_PANDA_UID
from sb3_memret.stage1.demos import record_demos
from sb3_memret.tasks.demos import DemoEpisode
from sb3_memret.stage1.datasets import Demonstrations, hindsight_objects, load_demonstrations, validation_episodes
from sb3_memret.stage1.finetune import FinetuneSettings, read_log, tasks_template
from sb3_memret.benchmark.runner import split_tasks
from sb3_memret.controllers.prompts import NUMBER, SIGNED_NUMBER, WORDS, parse_prompt
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.batteries_checker.checklist import CHECKLIST_PATTERN
from sb3_memret.stage1.finetune import finetune as finetune_any_task

SMALL = LearnedPolicyConfig(hidden_dim=64, n_layers=2, text_dim=32, text_heads=2, chunk_len=8)


def finetune(datasets, out, *args, **kwargs):
    """``finetune`` on the drawer's datasets."""
    return finetune_any_task(datasets, out, *args, task="drawer", **kwargs)


def at(seed: int, layer: int, kind: str) -> DemoEpisode:
    """A drawer demonstration with the cube in ``layer``, its prompt of ``kind`` worded by the task."""
    return DemoEpisode(seed, kind, reset_options={"target_layer": layer})


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    root = tmp_path_factory.mktemp("finetune") / "demos"
    episodes = [at(40, 1, "matching"), at(41, 3, "matching"), at(42, 2, "bare")]
    return record_demos(root, "drawer", episodes, max_steps=48)


def test_chunks_are_padded_at_each_episode_end():
    demos = Demonstrations(states=np.zeros((5, 19), np.float32), actions=np.arange(35, dtype=np.float32).reshape(5, 7),
                           episodes=np.array([0, 0, 0, 1, 1]), task_ids=np.zeros(5, np.int64), tasks=["x"], images={})
    index, pad = demos.chunk_indices(3)
    np.testing.assert_array_equal(index, [[0, 1, 2], [1, 2, 2], [2, 2, 2], [3, 4, 4], [4, 4, 4]])
    np.testing.assert_array_equal(pad, [[0, 0, 0], [0, 0, 1], [0, 1, 1], [0, 0, 1], [0, 1, 1]])


def test_the_validation_split_is_whole_episodes_rebuilt_from_the_seed():
    """A finetune's held-out episodes can be rebuilt from its seed (scripts/perception_error.py does)."""
    frames = np.repeat(np.arange(20), 5)
    held = validation_episodes(frames, 0.1, np.random.default_rng(0))
    assert len(held) == len(set(held.tolist())) == 2 and set(held.tolist()) <= set(range(20))
    np.testing.assert_array_equal(held, validation_episodes(frames, 0.1, np.random.default_rng(0)))
    assert len(validation_episodes(frames, 0.0, np.random.default_rng(0))) == 0


def test_datasets_are_read_with_their_prompts(demos):
    data = load_demonstrations([demos, demos], "drawer")
    assert data.states.shape == (288, 19) and data.actions.shape == (288, 7)
    assert sorted(data.tasks) == sorted({condition_prompt("oracle", 1), condition_prompt("oracle", 3), INSTRUCTION})
    assert len(np.unique(data.episodes)) == 6  # the second copy's episodes are new episodes
    with pytest.raises(FileNotFoundError, match="not a LeRobotDataset"):
        load_demonstrations([demos.parent], "drawer")


def test_policy_learns_the_experts_labels(demos, tmp_path):
    out = finetune([demos], tmp_path / "ckpt", SMALL, FinetuneSettings(steps=300, batch_size=64,
                                                                         validation_fraction=0.0))
    losses = [float(row["train_loss"]) for row in read_log(out)]
    assert losses[-1] < 0.5 * losses[0], losses
    controller = make_controller(f"learned:{out}", "drawer")
    assert controller.policy.config.training_prompts == tuple(sorted(load_demonstrations([demos], "drawer").tasks))
    data = load_demonstrations([demos], "drawer")
    first = np.flatnonzero(np.r_[True, np.diff(data.episodes) != 0])
    controller.reset(list(range(len(first))))
    obs = {"agent": {"eef_state": data.states[first, :8]},
           "extra": {"drawer_opening": data.states[first, 8:11], "target_detection": data.states[first, 11:]}}
    chunks = controller.act(obs, [data.tasks[t] for t in data.task_ids[first]])
    target = np.stack([data.actions[i: i + 8] for i in first])
    assert np.abs(chunks - target).mean() < 0.5 * np.abs(target).mean()


def test_prompts_outside_the_contract_are_refused_before_any_frame_is_read(demos, tmp_path, monkeypatch):
    import sb3_memret.stage1.finetune as module

    def no_frames(*args, **kwargs):
        raise AssertionError("the frames were read before the prompts were checked")

    monkeypatch.setattr(module, "load_demonstrations", no_frames)
    monkeypatch.setattr(module, "load_task_demonstrations", no_frames)
    config = LearnedPolicyConfig(fact_templates=("the robot is holding the {value}.",))
    with pytest.raises(ValueError, match="matches no trained template"):
        finetune([demos], tmp_path / "ckpt", config, FinetuneSettings(steps=1))
    with pytest.raises(ValueError, match="matches no trained template"):  # datasets given per task, too
        finetune_any_task({"drawer": [demos]}, tmp_path / "ckpt", config, FinetuneSettings(steps=1))


def test_demos_finetune_rollout_through_the_cli(tmp_path):
    from click.testing import CliRunner

    from sb3_memret.cli import main

    runner = CliRunner()
    result = runner.invoke(main, ["demos", "--episodes", "2", "--n-envs", "1", "--out", str(tmp_path / "d"), "--no-progress"])
    assert result.exit_code == 0 and "2 episodes" in result.output, result.output
    result = runner.invoke(main, ["demos", "--episodes", "1", "--n-envs", "1", "--max-steps", "30", "--out",
                                  str(tmp_path / "short"), "--no-progress"])
    assert result.exit_code == 0, result.output
    (episode,) = map(json.loads, (tmp_path / "short" / "sb3_memret_episodes.jsonl").open())
    assert episode["steps"] == 30 and not episode["success"]  # the expert needs more than 30 steps
    result = runner.invoke(main, ["finetune", str(tmp_path / "d"), "--out", str(tmp_path / "c"), "--set",
                                  "training.steps=20", "--no-progress"])
    assert result.exit_code == 0 and f"--controller learned:{tmp_path / 'c'}" in result.output, result.output
    result = runner.invoke(main, ["rollout", "--controller", f"learned:{tmp_path / 'c'}", "--episodes", "1",
                                  "--group", "2", "--json"])
    assert result.exit_code == 0, result.output
    result = runner.invoke(main, ["demos", "--out", str(tmp_path / "d")])
    assert result.exit_code == 2 and "already exists" in result.output
    result = runner.invoke(main, ["finetune", str(tmp_path / "d"), "--out", str(tmp_path / "p"), "--policy", "pi05"])
    assert result.exit_code == 2 and "policy pi05 needs its pretrained PI05 checkpoint folder" in result.output
    refusals = {
        ("model.image_head=64",): "model.image_head=64 is invalid; expected a list of [channels, kernel] convs",
        ("model.image_head=[[60, 3]]",): "channels a multiple of 8",
        ("model.image_encoder=cnn", "model.image_head=[[64, 3]]"): "model.image_head shape a frozen trunk's camera heads",
        ("model.image_encoder=cnn", "model.trunk_stride=4"): "model.trunk_stride shape a frozen trunk's camera heads",
        ("model.image_encoder=cnn", "model.trunk_scale=2"): "model.trunk_scale shape a frozen trunk's camera heads",
        ("model.trunk_stride=2",): "trunk_stride 2: expected one of [4, 8]",
        ("model.widht=3",): "unknown key model.widht; the model's keys are",
        ("training.steps=many",): "training.steps='many' is invalid; expected int",
        ("training.pointer_hindsight=0.1",): "trains the pointer: set model.pointer: true",
        ("steps=20",): "unknown key(s) ['steps']",
        ("training.steps",): "'training.steps' is not KEY=VALUE",
    }
    for sets, message in refusals.items():
        args = [arg for key in sets for arg in ("--set", key)]
        result = runner.invoke(main, ["finetune", str(tmp_path / "d"), "--out", str(tmp_path / "h"), *args])
        assert result.exit_code == 2 and message in result.output and not (tmp_path / "h").exists(), (sets, result.output)
    result = runner.invoke(main, ["finetune", str(tmp_path / "d"), "--out", str(tmp_path / "c"), "--resume"])
    assert result.exit_code == 2 and "nothing to resume" in result.output, result.output


@pytest.fixture(scope="module")
def camera_demos(tmp_path_factory):
    root = tmp_path_factory.mktemp("finetune") / "camera-demos"
    episodes = [at(43, 1, "matching"), at(44, 2, "matching")]
    return record_demos(root, "drawer", episodes, render_backend="cpu", max_steps=40, frames="decisions", image_size=32)


def test_training_reads_a_frame_as_the_controller_reads_the_observation_it_was_recorded_from(camera_demos, tmp_path):
    """One processor for both sides: the inputs a finetune builds from a recorded frame (state entries by name, camera
    images scaled, prompt features) equal those the controller builds from the observation the frame was recorded
    from, so a policy acts on what it learned from."""
    from dataclasses import replace

    from sb3_memret.controllers.learned import LearnedPolicy
    from sb3_memret.controllers.learned.processing import LearnedPolicyProcessor, PromptTokenizer
    from sb3_memret.stage1.finetune import DemoTensors, default_config, policy_config
    from sb3_memret.tasks.drawer import DrawerTask

    task = DrawerTask()
    demos = load_demonstrations([camera_demos], task)
    config, reads = policy_config(replace(default_config([task]), image_encoder="cnn", image_dim=8, chunk_len=8),
                                  [task], demos, "proprio", True, 1.0)
    model, tokenizer = LearnedPolicy(config), PromptTokenizer()
    data = DemoTensors.build(model, LearnedPolicyProcessor(model.config, tokenizer=tokenizer), demos, reads,
                             tokenizer(demos.tasks), np.random.default_rng(0),
                             FinetuneSettings(validation_fraction=0.0), [task], tmp_path, cache_features=False)
    trained = data.batch(np.array([0]), augment=False)  # the first frame: episode seed 43's reset, cube in layer 1
    env = task.make_env(obs_mode="rgb", render_backend="cpu", robot_uids=DEFAULT_ROBOT)
    obs, _ = env.reset(seed=43, options={"target_layer": 1, "target": "cube"})
    acting = LearnedPolicyProcessor(model.config, task, tokenizer)(obs, [condition_prompt("oracle", 1)])
    env.close()
    assert config.image_features and torch.equal(trained.state, acting["state"])
    assert len(trained.cameras) == len(acting["images"]) == 2
    for learned_from, acted_on in zip(trained.cameras, acting["images"]):
        assert learned_from.shape == acted_on.shape == (1, 3, 32, 32) and torch.equal(learned_from, acted_on)
    mask = acting["token_mask"][0]
    assert torch.equal(trained.token_mask[trained.prompt_of[0]][: len(mask)], mask)
    assert torch.equal(trained.tokens[trained.prompt_of[0]][: len(mask)][mask], acting["tokens"][0][mask])


def test_camera_frames_stay_on_disk_and_read_back_whole_by_dataset_or_by_index(camera_demos, tmp_path):
    """A set of demonstrations holds where its images lie, not the images: read back they are the dataset's frames,
    whole, a dataset at a time (two copies of one dataset joined: twice the frames, in order) or at chosen frames."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from sb3_memret.stage1.datasets import CameraFrames

    key = "observation.images.image"
    stored = np.asarray(LeRobotDataset("local/c", root=camera_demos).hf_dataset.with_format("numpy")[key])
    frames = load_demonstrations([camera_demos, camera_demos], "drawer").images[key]
    assert isinstance(frames, CameraFrames) and frames.shape == (2 * len(stored), 32, 32, 3)
    blocks = list(frames.blocks())
    assert len(blocks) == 2 and all(np.array_equal(block, stored) for block in blocks)
    assert np.array_equal(frames.array(), np.concatenate([stored, stored]))
    idx = np.array([len(stored) + 1, 0, 3])  # across both datasets, out of order
    assert np.array_equal(frames.take(idx), stored[[1, 0, 3]])
    with pytest.raises(IndexError, match=r"must lie in \[0, "):
        frames.take(np.array([len(frames)]))
    with pytest.raises(ValueError, match="cannot join"):
        CameraFrames.join([frames, CameraFrames(key, (tmp_path,), (1,), (64, 64, 3))])


def test_a_camera_policy_learns_from_decision_frames_and_sees_only_the_hand(camera_demos, demos, tmp_path, rgb_task_env):
    config = LearnedPolicyConfig(hidden_dim=64, n_layers=2, text_dim=32, text_heads=2, image_encoder="cnn", image_dim=16)
    out = finetune([camera_demos], tmp_path / "ckpt", config, FinetuneSettings(steps=150, batch_size=10,
                                                                                 validation_fraction=0.5),
                   state="proprio")
    losses = [float(row["train_loss"]) for row in read_log(out)]
    assert losses[-1] < 0.7 * losses[0], losses
    controller = make_controller(f"learned:{out}", "drawer")
    config = controller.policy.config
    assert config.state_names == PROPRIO_NAMES and config.image_size == 32 and controller.spec.needs_images
    assert config.robot == controller.spec.robot == DEFAULT_ROBOT  # the robot its demonstrations' cameras showed
    other = "panda" if DEFAULT_ROBOT == LIGHT_PANDA_UID else LIGHT_PANDA_UID
    with pytest.raises(ValueError, match=f"trained on camera images of robot '{DEFAULT_ROBOT}' but the env renders '{other}'"):
        controller.check_env(TaskEnvInfo("pd_ee_delta_pose", "rgb", other))
    controller.check_env(rgb_task_env)
    # what the hand does not read of itself, the cameras estimate: the drawer openings and the cube's detection
    assert config.perceived_names == STATE_NAMES[len(PROPRIO_NAMES):]
    perception = [float(row["val_perception_mse"]) for row in read_log(out)]
    assert perception[-1] < 0.7 * perception[0], perception
    fitted = [float(row["train_perception_mse"]) for row in read_log(out)]  # the batch's: beside the held-out one,
    assert fitted[-1] < 0.7 * fitted[0], fitted  # it tells overfitting from what the cameras cannot tell
    obs, _ = rgb_task_env.reset(seed=43, options={"target_layer": 1})
    controller.reset([43])
    assert controller.act(obs, [condition_prompt("oracle", 1)]).shape == (1, 32, 7)
    with pytest.raises(ValueError, match="cannot see where anything is"):
        finetune([demos], tmp_path / "blind", SMALL, FinetuneSettings(steps=1), state="proprio")
    with pytest.raises(ValueError, match="recorded with the same render backend"):
        load_demonstrations([camera_demos, demos], "drawer")


def test_a_frozen_trunks_features_are_cached_per_dataset_and_train_the_same_policy(camera_demos, tmp_path):
    """The second finetune of the same frames reads the first's trunk features from the cache (one file per camera)
    and, with the same seed, trains the very same weights as one that computes them afresh."""
    from safetensors.torch import load_file

    from sb3_memret.common.cache import cache_root
    from sb3_memret.stage1.feature_cache import FOLDER

    config = LearnedPolicyConfig(hidden_dim=32, n_layers=1, text_dim=16, text_heads=2, image_encoder="efficientnet_lite0",
                                 image_dim=8, keypoints=8)
    settings = FinetuneSettings(steps=3, batch_size=4)
    before = set((cache_root() / FOLDER).rglob("*.npy"))
    weights = []
    for name, cache in (("first", True), ("cached", True), ("fresh", False)):
        out = finetune([camera_demos], tmp_path / name, config, settings, state="proprio", cache_features=cache)
        weights.append(load_file(out / "model.safetensors"))
        if name == "first":
            assert len(set((cache_root() / FOLDER).rglob("*.npy")) - before) == 2  # the base and wrist cameras
    assert all(torch.equal(weights[0][key], other[key]) for other in weights[1:] for key in weights[0])


@pytest.mark.parametrize("priority", [0.0, 1.0])
def test_a_stopped_finetune_resumes_to_the_weights_of_one_never_stopped(camera_demos, tmp_path, priority):
    """Stopped after step 7, a finetune keeps its state; resumed, it trains the very same weights as a run that was
    never stopped (its optimiser, schedule, batches, frame errors and pixel shifts go on where they were) and logs
    every step once. A folder with an unfinished run is not overwritten, and other settings cannot resume it."""
    from safetensors.torch import load_file

    from sb3_memret.stage1.finetune import STATE_FILE

    config = LearnedPolicyConfig(hidden_dim=32, n_layers=1, text_dim=16, text_heads=2, image_encoder="cnn",
                                 image_dim=8, keypoints=8)
    settings = FinetuneSettings(steps=12, batch_size=8, priority=priority)
    whole = finetune([camera_demos], tmp_path / "whole", config, settings, state="proprio")
    assert not (whole / STATE_FILE).exists()

    def stop_after_7(step: int, loss: float) -> None:
        if step == 8:
            raise KeyboardInterrupt

    out = tmp_path / "stopped"
    with pytest.raises(KeyboardInterrupt):
        finetune([camera_demos], out, config, settings, state="proprio", on_step=stop_after_7)
    assert (out / STATE_FILE).is_file() and not (out / "model.safetensors").exists()
    with pytest.raises(FileExistsError, match="holds an unfinished finetune"):
        finetune([camera_demos], out, config, settings, state="proprio")
    with pytest.raises(ValueError, match="other datasets, settings or policy options"):
        finetune([camera_demos], out, config, FinetuneSettings(steps=12, batch_size=4), state="proprio", resume=True)
    steps = []
    finetune([camera_demos], out, config, settings, state="proprio", resume=True,
             on_step=lambda step, loss: steps.append(step))
    assert steps == list(range(8, 13)) and not (out / STATE_FILE).exists()
    assert [int(row["step"]) for row in read_log(out)] == list(range(1, 13))
    expected, resumed = load_file(whole / "model.safetensors"), load_file(out / "model.safetensors")
    assert all(torch.equal(expected[key], resumed[key]) for key in expected)
    with pytest.raises(FileNotFoundError, match="nothing to resume"):
        finetune([camera_demos], out, config, settings, state="proprio", resume=True)


def test_a_colour_reading_policy_round_trips_and_acts(camera_demos, tmp_path, rgb_task_env):
    config = LearnedPolicyConfig(hidden_dim=32, n_layers=1, text_dim=16, text_heads=2, image_encoder="efficientnet_lite0",
                                 image_dim=8, keypoints=8, image_colour=True)
    out = finetune([camera_demos], tmp_path / "ckpt", config, FinetuneSettings(steps=3, batch_size=4), state="proprio")
    controller = make_controller(f"learned:{out}", "drawer")
    assert controller.policy.config.image_colour and controller.policy.cameras[0].net[0].in_channels == 43
    obs, _ = rgb_task_env.reset(seed=43, options={"target_layer": 2})
    controller.reset([43])
    assert controller.act(obs, [condition_prompt("oracle", 2)]).shape == (1, 32, 7)


def test_a_prompt_conditioned_camera_policy_round_trips_and_its_vision_follows_the_prompt(camera_demos, tmp_path,
                                                                                          rgb_task_env):
    config = LearnedPolicyConfig(hidden_dim=32, n_layers=1, text_dim=16, text_heads=2, image_encoder="cnn",
                                 image_dim=8, keypoints=8, image_film=True)
    out = finetune([camera_demos], tmp_path / "ckpt", config, FinetuneSettings(steps=3, batch_size=4), state="proprio")
    controller = make_controller(f"learned:{out}", "drawer")
    policy = controller.policy
    assert policy.config.image_film and all(head.film is not None for head in policy.cameras)
    obs, _ = rgb_task_env.reset(seed=43, options={"target_layer": 2})
    controller.reset([43])
    assert controller.act(obs, [condition_prompt("oracle", 2)]).shape == (1, 32, 7)
    prompts = [condition_prompt("oracle", 1), condition_prompt("oracle", 3)]
    inputs = controller.processor(obs, prompts[:1])
    features = [f.expand(2, -1, -1, -1) for f in policy.camera_features(inputs["images"])]
    with torch.no_grad():
        vision = policy.encode_cameras(features, policy.encode_prompts(*controller.processor.tokenizer(prompts)))
        assert not torch.allclose(vision[0], vision[1])  # one frame, two prompts: two views of it
        with pytest.raises(ValueError, match="conditioned on the prompt"):
            policy.encode_cameras(features)


def test_a_policy_without_cameras_estimates_nothing(demos, tmp_path):
    out = finetune([demos], tmp_path / "ckpt", SMALL, FinetuneSettings(steps=2, batch_size=8))
    assert make_controller(f"learned:{out}", "drawer").policy.config.perceived_names == ()
    rows = read_log(out)
    assert {row["val_perception_mse"] for row in rows} == {row["train_perception_mse"] for row in rows} == {""}


def test_the_pointer_ambiguity_is_zero_when_each_prompt_points_at_its_own_object_and_largest_when_none_tells():
    eye = torch.eye(3)
    assert float(pointer_ambiguity(eye)) == pytest.approx(0.0, abs=1e-6)  # three prompts, three objects
    assert float(pointer_ambiguity(torch.full((4, 3), 1 / 3))) == pytest.approx(np.log(3), rel=1e-5)  # spread
    assert float(pointer_ambiguity(eye[[0, 0, 0]])) == pytest.approx(np.log(3), rel=1e-5)  # a collapse onto one
    partial = float(pointer_ambiguity(eye[[0, 1, 1]]))  # two of three prompts share an object
    assert 0 < partial < np.log(3)


def test_hindsight_points_each_prompt_at_the_object_its_episodes_hands_mostly_end_nearest():
    """Two objects, three prompts: prompt 0's hands end at a every time, prompt 1's at b in two episodes of three,
    prompt 2's episodes disagree one to one and get no target. Only the frames given vote."""
    names = ("tcp_x", "tcp_y", "tcp_z", "a_x", "a_y", "a_z", "b_x", "b_y", "b_z")
    a, b = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]
    ends = {"a": [0.1, 0.0, 0.0], "b": [0.9, 0.0, 0.0]}
    finals = [(0, "a"), (0, "a"), (1, "b"), (1, "b"), (1, "a"), (2, "a"), (2, "b")]
    states, episodes, prompts = [], [], []
    for episode, (prompt, end) in enumerate(finals):  # two frames an episode: the hand starts between, then ends
        states += [[0.5, 0.0, 0.3] + a + b, ends[end] + a + b]
        episodes += [episode, episode]
        prompts += [prompt, prompt]
    demos = Demonstrations(states=np.array(states, np.float32), actions=np.zeros((len(states), 7), np.float32),
                           episodes=np.array(episodes), task_ids=np.array(prompts), tasks=["p0", "p1", "p2"],
                           images={}, state_names=names)
    assert hindsight_objects(demos, names[:3], ("a", "b")).tolist() == [0, 1, -1]
    without_episode_5 = np.array(episodes) != 5  # prompt 2 is then b's alone
    assert hindsight_objects(demos, names[:3], ("a", "b"), without_episode_5).tolist() == [0, 1, 1]
    with pytest.raises(ValueError, match="hand_z"):
        hindsight_objects(demos, ("tcp_x", "tcp_y", "hand_z"), ("a", "b"))


def test_hindsight_reads_where_the_hand_was_when_a_progress_fact_changed_the_prompt():
    """One episode of a sequence: under prompt 0 the hand goes to a (then a fact is written), under prompt 1 to b.
    Each prompt points at the object its own frames end at, not at the episode's last."""
    names = ("tcp_x", "tcp_y", "tcp_z", "a_x", "a_y", "a_z", "b_x", "b_y", "b_z")
    a, b = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]
    hands = [[0.5, 0.0, 0.3], [0.1, 0.0, 0.0], [0.5, 0.0, 0.3], [0.9, 0.0, 0.0]]
    states = np.array([hand + a + b for hand in hands], np.float32)
    demos = Demonstrations(states=states, actions=np.zeros((4, 7), np.float32), episodes=np.zeros(4, int),
                           task_ids=np.array([0, 0, 1, 1]), tasks=["p0", "p0 then a"], images={}, state_names=names)
    assert demos.prompt_ends().tolist() == [1, 3] and demos.last_frames().tolist() == [3]
    assert hindsight_objects(demos, names[:3], ("a", "b")).tolist() == [0, 1]


def test_hindsight_never_points_at_an_object_the_episodes_task_lacks():
    """Two tasks merged: b exists only in the second, so the first's frames hold b at 0 (where its hand ends);
    its prompt still points at a, the nearest object it has."""
    names = ("tcp_x", "tcp_y", "tcp_z", "a_x", "a_y", "a_z", "b_x", "b_y", "b_z")
    states = np.array([[0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0],  # task 1: no b, the hand ends at b's zeros
                       [1.0, 0.0, 0.0, 0.3, 0.0, 0.0, 1.0, 0.0, 0.0]], np.float32)  # task 2: the hand ends at b
    known = np.ones(states.shape, dtype=bool)
    known[0, 6:] = False
    demos = Demonstrations(states=states, actions=np.zeros((2, 7), np.float32), episodes=np.array([0, 1]),
                           task_ids=np.array([0, 1]), tasks=["p0", "p1"], images={}, state_names=names, known=known)
    assert hindsight_objects(demos, names[:3], ("a", "b")).tolist() == [0, 1]
    demos.known = None
    assert hindsight_objects(demos, names[:3], ("a", "b")).tolist() == [1, 1]  # unmasked, b's zeros would win


# a sentence each field pattern of the MIKASA tasks takes (a new pattern fails the test below until it has one)
FIELD_SAMPLES = {NUMBER: "12", SIGNED_NUMBER: "-30", WORDS: "blue lamp",
                 CHECKLIST_PATTERN: "slot 1 working and slot 2 dead"}


def test_one_contract_across_every_mikasa_task_takes_each_tasks_own_sentences():
    """A policy trained on several tasks takes every task's instructions and facts, though the tasks word a field
    differently (TimedTransfer's {count} a number of steps, BlinkCount's words)."""
    names = sorted({name for split in ("short", "medium", "long") for name in split_tasks(split)[0]})
    tasks = [make_task(name) for name in names]
    merged = tasks_template(tasks)
    for task in tasks:
        own = task.prompt_template
        values = {}
        for name, pattern in own.field_patterns():
            assert pattern in FIELD_SAMPLES, f"{task.name}: no sample for field {name!r}'s pattern {pattern!r}"
            values.setdefault(name, FIELD_SAMPLES[pattern])
        for sentence in own.fact_templates:
            prompt = f"{own.instructions[0].format(**values)} {sentence.format(**values)}"
            fact = parse_prompt(prompt, own).facts[0]  # the sample is one the task itself takes
            assert dict(fact.fields) == {k: v for k, v in values.items() if "{" + k + "}" in sentence}
            assert parse_prompt(prompt, merged).facts[0].template in merged.fact_templates, (task.name, sentence)
        for instruction in task.instruction_templates:
            assert parse_prompt(instruction.format(**values), merged).instruction == instruction.format(**values)
