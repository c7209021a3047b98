"""MIKASA-Robo-VLA's RememberColor tasks in the memory loop: the writer's fact comes from the camera,
prompts follow the task's contract, evaluation plays development seeds (MIKASA's own stay unseen), and the CLI
runs them."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from sb3_memret.cli import main
from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.core.cue_task import DEV_SEED
from sb3_memret.tasks.mikasa.remember.color import EVAL_SEED, RememberColorTask

TASK = "RememberColor3-VLA-v0"


def test_the_three_sizes_are_registered_and_other_ids_refused():
    for n in (3, 5, 9):
        task = make_task(f"RememberColor{n}-VLA-v0")
        assert isinstance(task, RememberColorTask) and len(task.colours) == n
    assert make_task(TASK).evaluation_seeds(3) == [EVAL_SEED, EVAL_SEED + 1, EVAL_SEED + 2] == [4242424242, 4242424243,
                                                                                                 4242424244]
    assert make_task(TASK).development_seeds(2) == [DEV_SEED, DEV_SEED + 1] == [5000, 5001]  # never the protocol's
    with pytest.raises(ValueError, match="unknown RememberColor task 'RememberColor4-VLA-v0'"):
        RememberColorTask("RememberColor4-VLA-v0")
    with pytest.raises(ValueError, match="ShellGameTouch-VLA-v0' is not available: .*YCB mug"):
        make_task("ShellGameTouch-VLA-v0")


def test_without_a_renderer_the_task_refuses_in_one_line():
    with pytest.raises(ValueError, match="need a renderer .* --render-backend cpu"):
        make_task(TASK).env_kwargs(needs_images=False, render_backend="none")


def test_the_cue_fact_is_written_from_the_camera_and_retrieved(encoder):
    """Recall with the true slot on one episode: the fact appears once the cue was seen, it names the
    episode's colour, and the expert succeeds through it; decoys are worded alike."""
    venv = make_recall_vec_env(1, {"task": TASK, "controller": "scripted", "encoder": encoder, "replan_every": 4,
                                   "capacity": 6, "location_decoys": 5, "render_backend": "cpu"}, seed=0)
    try:
        venv.set_task_seeds([[DEV_SEED]])
        venv.reset()
        memory = venv.venv.memories[0]
        colour = memory.truth.group
        assert venv.venv.episode_task_seeds == [DEV_SEED]
        done, success, retrieved = False, False, []
        while not done:
            slot = memory.true_slot()
            obs, _, dones, infos = venv.step(np.array([[max(slot, 0)]]))
            done, success = bool(dones[0]), bool(infos[0]["success"])
            retrieved.append(infos[0]["retrieved_true"])
            if not done:
                texts = [e.text for e in memory.bank.entries]
        assert f"the cue cube was {colour}." in texts
        assert all(t.endswith(".") and " was " in t for t in texts)
        assert any(retrieved) and success and infos[0]["group"] == colour and infos[0]["task_seed"] == DEV_SEED
    finally:
        venv.close()


@pytest.mark.parametrize("condition, expected", [("oracle", 1.0), ("wrong", 0.0)])
def test_rollout_runs_a_mikasa_task_at_its_development_seeds(condition, expected):
    result = CliRunner().invoke(main, ["rollout", "--task", TASK, "--controller", "scripted", "--condition", condition,
                                       "--episodes", "2", "--replan-every", "4", "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output.strip().splitlines()[-1])
    assert summary["task"] == TASK and summary["seeds"] == [DEV_SEED, DEV_SEED + 1]
    assert summary["success"]["overall"] == expected


def test_rollout_plays_seeds_of_ones_choosing_but_never_beside_the_test_set():
    args = ["rollout", "--task", TASK, "--controller", "scripted", "--condition", "oracle", "--episodes", "1",
            "--seed", "6000", "--json"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output.strip().splitlines()[-1])
    assert summary["seeds"] == [6000] and summary["success"]["overall"] == 1.0
    result = CliRunner().invoke(main, [*args, "--seeds", "protocol"])
    assert result.exit_code == 2 and "--seeds protocol plays the task's own test set" in result.output


def test_rollout_refuses_a_group_on_a_task_whose_env_draws_its_groups():
    result = CliRunner().invoke(main, ["rollout", "--task", TASK, "--controller", "scripted", "--group", "2"])
    assert result.exit_code == 2 and ("task 'RememberColor3-VLA-v0' has no group '2' to choose; expected none: its env "
                                      "draws every episode's group itself") in result.output


@pytest.fixture(scope="module")
def every_step_demos(tmp_path_factory):
    """Two expert episodes of RememberColor3 with every control step kept (both cameras rendered)."""
    out = tmp_path_factory.mktemp("mikasa") / "rc3"
    result = CliRunner().invoke(main, ["demos", "--task", TASK, "--episodes", "2", "--seed", "100005", "--n-envs", "1",
                                       "--noisy-fraction", "0", "--frames", "every", "--out", str(out), "--no-progress"])
    assert result.exit_code == 0, result.output
    return out


def test_demos_of_a_mikasa_task_are_a_lerobot_dataset_whose_prompts_carry_the_fact(every_step_demos):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from sb3_memret.stage1.demos import read_episode_log
    from sb3_memret.tasks.mikasa.core.demo_layout import state_names

    out = every_step_demos
    log = read_episode_log(out)
    assert [r["seed"] for r in log] == [100005, 100006] and {r["prompt_kind"] for r in log} == {"matching", "mismatched"} and all(r["frames"] == 25 for r in log)
    dataset = LeRobotDataset("sb3_memret/rc3", root=out)
    assert len(dataset) == 50 and dataset.meta.features["observation.state"]["names"] == list(
        state_names(make_task(TASK).colours))
    frame = dataset[0]
    assert frame["observation.state"].shape == (37,) and frame["observation.images.image"].shape == (3, 128, 128)
    for record in log:
        kind, prompt, colour = record["prompt_kind"], record["prompt"], record["group"]
        if kind == "matching":
            assert prompt.endswith(f"the cue cube was {colour}.") and record["success"]
        elif kind == "mismatched":
            assert "the cue cube was" in prompt and not prompt.endswith(f"{colour}.")
    assert {dataset[i]["task"] for i in range(0, 50, 25)} == {r["prompt"] for r in log}


def test_a_pointer_camera_policy_finetunes_on_mikasa_demos_and_logs_its_ambiguity(every_step_demos, tmp_path):
    """``finetune --set model.pointer=true`` on a MIKASA task: the pointer groups the perceived cubes, its ambiguity is logged
    (log 3 at most for three cubes), and the checkpoint loads as a controller with its pointer."""
    from sb3_memret.controller_specs import make_controller
    from sb3_memret.stage1.finetune import read_log

    out = tmp_path / "policy"
    result = CliRunner().invoke(main, ["finetune", str(every_step_demos), "--task", TASK, "--set", "training.steps=4",
                                       "--set", "training.batch_size=8", "--set", "model.pointer=true", "--no-progress",
                                       "--out", str(out)])
    assert result.exit_code == 0, result.output
    ambiguity = [float(row["pointer_ambiguity"]) for row in read_log(out)]
    assert len(ambiguity) == 4 and all(0 <= a <= np.log(3) + 1e-6 for a in ambiguity)
    controller = make_controller(f"learned:{out}", task=make_task(TASK))
    assert controller.policy.pointer is not None and controller.policy.config.pointer_fields == 4


def test_pointer_hindsight_points_each_prompt_at_the_cube_its_hand_ended_at(every_step_demos, tmp_path):
    """``finetune`` with the pointer and its hindsight loss: each prompt's target is the cube the expert's hand ended nearest
    (the matching prompt's: the cue's colour), written to pointer_targets.json, and the pointer learns to point
    there; without the pointer the option is refused."""
    import json

    from sb3_memret.controllers.learned import LearnedPolicy
    from sb3_memret.controllers.learned.processing import PromptTokenizer
    from sb3_memret.stage1.demos import read_episode_log

    out = tmp_path / "policy"
    result = CliRunner().invoke(main, ["finetune", str(every_step_demos), "--task", TASK, "--set", "training.steps=30",
                                       "--set", "training.batch_size=8", "--set", "training.learning_rate=0.01", "--set", "model.pointer=true", "--set", "training.pointer_hindsight=1",
                                       "--no-progress", "--out", str(out)])
    assert result.exit_code == 0, result.output
    targets = json.loads((out / "pointer_targets.json").read_text())
    matching = next(r for r in read_episode_log(every_step_demos) if r["prompt_kind"] == "matching")
    assert targets[matching["prompt"]] == f"cube_{matching['group']}" and len(targets) == 2
    policy = LearnedPolicy.from_pretrained(out)
    objects = [name.removesuffix("_x") for name in policy.config.perceived_names if name.endswith("_x")]
    prompts = list(targets)
    weights = policy.pointer.weights(policy.encode_prompts(*PromptTokenizer()(prompts)))
    assert [objects[i] for i in weights.argmax(dim=1).tolist()] == [targets[p] for p in prompts]
    refused = CliRunner().invoke(main, ["finetune", str(every_step_demos), "--task", TASK, "--set", "training.pointer_hindsight=1",
                                        "--out", str(tmp_path / "refused")])
    assert refused.exit_code == 2 and "set model.pointer: true" in refused.output


def test_demos_refuse_options_a_mikasa_task_does_not_take(tmp_path):
    result = CliRunner().invoke(main, ["demos", "--task", TASK, "--objects", "train", "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "--objects" in result.output and "has no option ['objects']" in result.output
    result = CliRunner().invoke(main, ["demos", "--task", TASK, "--image-size", "200", "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "image_size must be in [16, 128]" in result.output


def test_mikasa_demos_with_cameras_keep_the_decision_frames_and_their_chunks(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from sb3_memret.controllers.observation import ACTION_CHUNK_KEY, CHUNK_PAD_KEY
    from sb3_memret.stage1.demos import read_episode_log

    out = tmp_path / "rc3"
    result = CliRunner().invoke(main, ["demos", "--task", TASK, "--episodes", "1", "--seed", "100005", "--n-envs", "1",
                                       "--out", str(out), "--no-progress"])
    assert result.exit_code == 0, result.output
    assert {k: read_episode_log(out)[0][k] for k in ("frames", "steps")} == {"frames": 7, "steps": 25}  # every 4th step
    dataset = LeRobotDataset("sb3_memret/rc3", root=out)
    last = dataset[6]
    assert last[ACTION_CHUNK_KEY].shape[1] == 7 and int((~last[CHUNK_PAD_KEY]).sum()) == 1  # step 24 is the last


def test_decision_frames_are_recorded_alike_with_the_cameras_paused_between_decisions():
    """Keeping decision frames only, the recorder renders only the observations it keeps: the steps between pause
    the cameras, and every kept image, state and label is the same as with every step rendered."""
    from sb3_memret.stage1.demos import DemoRecorder
    from sb3_memret.tasks.demos import DemoEpisode

    recorder = DemoRecorder(make_task(TASK), "cpu", frames="decisions")
    renders = []
    try:
        gate = vars(recorder.env.unwrapped)["_sb3_memret_sensor_gate"]
        render = gate._render  # ManiSkill's own: counted
        gate._render = lambda *args: renders.append(1) or render(*args)
        episode = DemoEpisode(100_005, "matching")
        paused = recorder.record(episode)
        paused_renders, renders[:] = len(renders), []
        recorder.pause = None
        rendered = recorder.record(episode)
    finally:
        recorder.env.close()
    assert paused.success and len(paused.frames) == 7 and len(renders) == 26  # the reset and each of the 25 steps
    assert paused_renders == 7  # the reset (decision 1) and the 6 chunk ends that decisions 2-7 read
    np.testing.assert_array_equal(paused.actions, rendered.actions)
    for kept, every in zip(paused.frames, rendered.frames, strict=True):
        assert kept.keys() == every.keys()
        for key in kept:
            np.testing.assert_array_equal(kept[key], every[key])


def test_max_steps_ends_a_recorded_episode_early_and_a_bad_one_is_refused():
    from sb3_memret.stage1.demos import DemoRecorder
    from sb3_memret.tasks.demos import DemoEpisode

    with pytest.raises(ValueError, match="max_steps must be >= 1"):
        DemoRecorder(make_task(TASK), "cpu", max_steps=0)
    recorder = DemoRecorder(make_task(TASK), "cpu", frames="decisions", max_steps=10)
    try:
        recorded = recorder.record(DemoEpisode(100_005, "bare"))
    finally:
        recorder.env.close()
    assert len(recorded.actions) == 10 and list(recorded.frame_steps) == [0, 4, 8]  # MIKASA's own limit: 60


def test_a_dagger_round_on_a_mikasa_task_follows_the_learner_with_the_experts_labels():
    from sb3_memret.stage1.demos import DemoRecorder
    from sb3_memret.tasks.demos import DemoEpisode
    from sb3_memret.tasks.mikasa.core.demo_layout import state_names
    from sb3_memret.tasks.mikasa.core.touch_expert import ScriptedTouchController

    task = make_task(TASK)

    class Stubborn(ScriptedTouchController):
        """A learner that never reads the fact: it touches the first colour, whatever its prompt says."""

        def act(self, obs, prompts, check_prompts=True):
            return super().act(obs, [task.instruction_text] * len(prompts), check_prompts)

    expert = task.expert()
    learner = Stubborn(vocabulary=expert.vocabulary, field=expert.field, prompt_template=expert.spec.prompt_template,
                       key=expert.key, default=expert.default)
    recorder = DemoRecorder(task, "cpu", replan_every=4, learner=learner)
    try:
        seed = next(s for s in range(100_000, 100_020) if recorder.record(DemoEpisode(s, "bare")).group != "red")
        recorded = recorder.record(DemoEpisode(seed, "matching"))
    finally:
        recorder.env.close()
    assert recorded.learner_acted and not recorded.success and recorded.group != "red"
    names = list(state_names(task.colours))
    last = recorded.frames[-1]["observation.state"]
    tcp = last[[names.index("tcp_x"), names.index("tcp_y")]]
    red = last[[names.index("cube_red_x"), names.index("cube_red_y")]]
    assert np.linalg.norm(tcp - red) < 0.05  # the learner went to red ...
    # ... while the labels, the expert's on the learner's states, kept asking to move on to the cue's cube
    assert np.all(np.abs(recorded.actions[-4:, :2]).max(axis=1) > 0.5)
