"""One camera controller over several tasks: their demonstrations merged on the union of their layouts, each
frame's perception loss on its own task's entries, one checkpoint that serves every task it was trained on."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from sb3_memret.cli import main
from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers.harness_proprio import HARNESS_PROPRIO_NAMES
from sb3_memret.stage1.datasets import load_task_demonstrations
from sb3_memret.controllers.learned.modeling import masked_mse
from sb3_memret.stage1.finetune import masked_stats, read_log
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.core.demo_layout import proprio_names

COLOUR, SHAPE = "RememberColor3-VLA-v0", "RememberShape3-VLA-v0"
REPO = Path(__file__).resolve().parents[1]
SMALL = ["--set", "model.image_encoder=cnn", "--set", "model.image_dim=8", "--set", "model.keypoints=4", "--set",
         "training.batch_size=8", "--no-progress"]


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    """One expert episode of each task, decision frames with both cameras."""
    root = tmp_path_factory.mktemp("multi-task-controller")
    out = {}
    for task, seed in ((COLOUR, 100011), (SHAPE, 100012)):
        out[task] = root / task
        result = CliRunner().invoke(main, ["demos", "--task", task, "--episodes", "1", "--seed", str(seed),
                                           "--n-envs", "1", "--noisy-fraction", "0", "--out", str(out[task]),
                                           "--no-progress"])
        assert result.exit_code == 0, result.output
    return out


def test_the_tasks_demonstrations_merge_on_the_union_of_their_layouts(datasets):
    demos, tasks = load_task_demonstrations({COLOUR: [datasets[COLOUR]], SHAPE: [datasets[SHAPE]]})
    colour, shape = (make_task(name).state_names() for name in (COLOUR, SHAPE))
    assert [t.name for t in tasks] == [COLOUR, SHAPE]
    assert demos.state_names == colour + tuple(n for n in shape if n not in colour)  # proprioception once, then each's
    assert set(proprio_names()) <= set(colour) & set(shape)
    is_colour = demos.known[:, demos.state_names.index("cube_red_x")]
    assert 0 < is_colour.sum() < len(demos.states) and demos.known[:, :len(proprio_names())].all()
    assert (demos.known[:, demos.state_names.index("shape_sphere_x")] == ~is_colour).all()
    assert not demos.states[~demos.known].any()  # entries a frame's task lacks hold 0
    assert len(np.unique(demos.episodes)) == 2 and len(demos.tasks) == 2  # one episode, one prompt each
    assert all(("cube's color" in p) == c for p, c in zip(np.array(demos.tasks)[demos.task_ids], is_colour))
    assert (demos.sources == ~is_colour).all()  # each frame's task, in the mapping's order


def test_draws_by_error_within_each_task_hand_the_sampler_every_training_frames_task(datasets, tmp_path, monkeypatch):
    from sb3_memret.stage1 import finetune as module
    from sb3_memret.stage1.sampling import FrameSampler

    made = []

    class Recorded(FrameSampler):
        def __init__(self, frames, priority=0.0, strata=None):
            made.append((frames, strata))
            super().__init__(frames, priority, strata)

    monkeypatch.setattr(module, "FrameSampler", Recorded)
    for within in ("task", "split"):
        result = CliRunner().invoke(main, ["finetune", str(datasets[COLOUR]), str(datasets[SHAPE]), "--tasks",
                                           f"{COLOUR},{SHAPE}", "--out", str(tmp_path / within), "--set",
                                           "training.steps=2", "--set", "training.priority=3.0", "--set",
                                           f"training.priority_within={within}", *SMALL])
        assert result.exit_code == 0, result.output
    demos, _ = load_task_demonstrations({COLOUR: [datasets[COLOUR]], SHAPE: [datasets[SHAPE]]})
    (frames, strata), (_, unstratified) = made
    assert np.array_equal(strata, demos.sources[frames]) and set(strata) == {0, 1} and unstratified is None
    result = CliRunner().invoke(main, ["finetune", str(datasets[COLOUR]), "--tasks", COLOUR, "--out",
                                       str(tmp_path / "bad"), "--set", "training.priority_within=episode", *SMALL])
    assert result.exit_code != 0 and "priority_within must be one of ['split', 'task'], got 'episode'" in result.output


def test_masked_statistics_and_loss_read_only_the_marked_entries():
    values = np.array([[1.0, 0.0], [3.0, 5.0], [0.0, 7.0]], dtype=np.float32)
    mask = np.array([[True, False], [True, True], [False, True]])
    mean, std = masked_stats(values, mask)
    assert mean.tolist() == [2.0, 6.0] and std.tolist() == [1.0, 1.0]
    predicted, target = torch.tensor([[1.0, 9.0]]), torch.tensor([[0.0, 0.0]])
    assert masked_mse(predicted, target, torch.tensor([[True, False]])).item() == 1.0  # the unmarked 81 left out
    assert masked_mse(predicted, target, torch.ones(1, 2, dtype=torch.bool)).item() == pytest.approx(41.0)


def test_one_camera_controller_is_trained_on_both_tasks_and_serves_each(datasets, tmp_path):
    out = tmp_path / "ckpt"
    result = CliRunner().invoke(main, ["finetune", str(datasets[COLOUR]), str(datasets[SHAPE]), "--tasks",
                                       f"{COLOUR},{SHAPE}", "--out", str(out), "--set", "training.steps=40", *SMALL])
    assert result.exit_code == 0, result.output
    losses = [float(row["train_loss"]) for row in read_log(out)]
    assert np.isfinite(losses).all() and losses[-1] < losses[0]
    controller = make_controller(f"learned:{out}", COLOUR)
    config = controller.policy.config
    assert config.served_tasks == (COLOUR, SHAPE) and config.state_names == proprio_names()
    assert {"cube_red_x", "shape_sphere_x"} <= set(config.perceived_names)
    assert set(config.instructions) == {make_task(t).prompt_template.instructions[0] for t in (COLOUR, SHAPE)}
    for name in (COLOUR, SHAPE):  # it acts on each task's cameras and prompts (a 40-step policy: success not asked)
        result = CliRunner().invoke(main, ["rollout", "--task", name, "--controller", f"learned:{out}", "--condition",
                                           "oracle", "--episodes", "1", "--seed", "5000"])
        assert result.exit_code == 0, result.output
    with pytest.raises(ValueError, match=rf"trained on task '{COLOUR}' or '{SHAPE}', not 'RememberColor5-VLA-v0'"):
        make_controller(f"learned:{out}", "RememberColor5-VLA-v0")


@pytest.mark.parametrize("tasks, message", [
    (f"{COLOUR}", "1 tasks for 2 datasets"),
    (f"{COLOUR},{COLOUR}", "names one task"),
    (f"{COLOUR},NoSuchTask-v0", "NoSuchTask-v0"),
])
def test_datasets_and_their_tasks_must_pair(datasets, tmp_path, tasks, message):
    result = CliRunner().invoke(main, ["finetune", str(datasets[COLOUR]), str(datasets[SHAPE]), "--tasks", tasks,
                                       "--out", str(tmp_path / "x"), *SMALL])
    assert result.exit_code == 2 and message in result.output and "--tasks" in result.output


def test_a_full_state_policy_over_tasks_whose_layouts_differ_is_refused(datasets, tmp_path):
    result = CliRunner().invoke(main, ["finetune", str(datasets[COLOUR]), str(datasets[SHAPE]), "--tasks",
                                       f"{COLOUR},{SHAPE}", "--set", "state=full", "--out", str(tmp_path / "x"), *SMALL])
    assert result.exit_code == 2 and "train it with state='proprio'" in result.output


def _chunks(root, datasets, tasks):
    """``root/TASK/chunk0`` (+ ``.done``), as scripts/record_task_demos.sh leaves a finished chunk."""
    for task in tasks:
        (root / task).mkdir(parents=True)
        (root / task / "chunk0").symlink_to(datasets[task])
        (root / task / "chunk0.done").touch()
    return root


def _finetune_script(*args):
    return subprocess.run(["bash", str(REPO / "scripts" / "finetune_task_demos.sh"), *map(str, args)],
                          capture_output=True, text=True, timeout=600)


def test_the_finetune_script_trains_one_policy_on_the_chunks_of_every_root(datasets, tmp_path):
    expert = _chunks(tmp_path / "demos", datasets, (COLOUR, SHAPE))
    dagger = _chunks(tmp_path / "dagger", datasets, (COLOUR, SHAPE))
    result = _finetune_script(f"{expert},{dagger}", tmp_path / "policy", f"{COLOUR},{SHAPE}", "--set", "training.steps=3", *SMALL)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "finetuning on 4 chunks of 2 task(s)" in result.stdout
    config = make_controller(f"learned:{tmp_path / 'policy'}", SHAPE).policy.config
    assert config.served_tasks == (COLOUR, SHAPE)


def test_the_finetune_script_refuses_a_root_that_lacks_a_task(datasets, tmp_path):
    expert = _chunks(tmp_path / "demos", datasets, (COLOUR, SHAPE))
    dagger = _chunks(tmp_path / "dagger", datasets, (COLOUR,))
    result = _finetune_script(f"{expert},{dagger}", tmp_path / "policy", f"{COLOUR},{SHAPE}", *SMALL)
    assert result.returncode == 2 and f"no finished chunks of {SHAPE} under {dagger}" in result.stderr
    assert not (tmp_path / "policy").exists()


def test_an_optional_root_adds_the_chunks_of_the_tasks_it_has(datasets, tmp_path):
    expert = _chunks(tmp_path / "demos", datasets, (COLOUR, SHAPE))
    more = _chunks(tmp_path / "more", datasets, (SHAPE,))  # more episodes of one task only
    result = _finetune_script(f"{expert},{more}?", tmp_path / "policy", f"{COLOUR},{SHAPE}", "--set", "training.steps=2", *SMALL)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "finetuning on 3 chunks of 2 task(s)" in result.stdout
    nothing = tmp_path / "nothing"
    nothing.mkdir()
    result = _finetune_script(f"{more}?,{nothing}?", tmp_path / "none", f"{COLOUR},{SHAPE}", *SMALL)
    assert result.returncode == 2 and f"no finished chunks of {COLOUR} under any of" in result.stderr
    assert not (tmp_path / "none").exists()


def test_the_finetune_script_resumes_an_unfinished_finetune(datasets, tmp_path):
    """An OUT holding a finetune's state is resumed (here one that cannot be read, refused by name)."""
    expert = _chunks(tmp_path / "demos", datasets, (COLOUR, SHAPE))
    out = tmp_path / "policy"
    out.mkdir()
    (out / "training_state.pt").write_bytes(b"not a state")
    result = _finetune_script(expert, out, f"{COLOUR},{SHAPE}", "--set", "training.steps=2", *SMALL)
    assert "resuming the unfinished finetune" in result.stdout
    assert result.returncode == 2 and "cannot be read as a finetune's state" in result.stderr, result.stderr


def test_the_finetune_script_keeps_a_finished_finetune_of_the_same_inputs_and_refuses_other_ones(datasets, tmp_path):
    """A make target that runs again passes a finished policy by; one trained on other chunks or options is not
    overwritten."""
    expert = _chunks(tmp_path / "demos", datasets, (COLOUR, SHAPE))
    out = tmp_path / "policy"
    args = (expert, out, f"{COLOUR},{SHAPE}", "--set", "training.steps=2", *SMALL)
    first = _finetune_script(*args)
    assert first.returncode == 0, first.stdout + first.stderr
    weights = (out / "model.safetensors").read_bytes()
    again = _finetune_script(*args)
    assert again.returncode == 0 and "already holds this finetune" in again.stdout, again.stdout + again.stderr
    assert "finetuning on" not in again.stdout and (out / "model.safetensors").read_bytes() == weights
    other = _finetune_script(*args[:3], "--set", "training.steps=3", *SMALL)
    assert other.returncode == 2 and "finetuned on other chunks or options" in other.stderr, other.stderr
    (out / "finetune_inputs.txt").unlink()  # a finished policy without its record is not taken for this one
    assert _finetune_script(*args).returncode == 2
    assert (out / "model.safetensors").read_bytes() == weights


def test_a_pointer_across_tasks_points_with_the_fields_every_object_has(datasets, tmp_path):
    back = "TakeItBack-VLA-v0"  # its cube has a position and no visibility flag, RememberColor3's cubes have both
    demos = tmp_path / back
    result = CliRunner().invoke(main, ["demos", "--task", back, "--episodes", "1", "--seed", "100013", "--n-envs", "1",
                                       "--noisy-fraction", "0", "--out", str(demos), "--no-progress"])
    assert result.exit_code == 0, result.output
    out = tmp_path / "ckpt"
    result = CliRunner().invoke(main, ["finetune", str(datasets[COLOUR]), str(demos), "--tasks", f"{COLOUR},{back}",
                                       "--set", "model.pointer=true", "--set", "training.pointer_hindsight=0.1", "--out", str(out), "--set", "training.steps=5",
                                       *SMALL])
    assert result.exit_code == 0, result.output
    config = make_controller(f"learned:{out}", back).policy.config
    assert {"cube_red_visible", "cube_x"} <= set(config.perceived_names) and "cube_visible" not in config.perceived_names
    assert config.pointer_fields == 3  # x, y, z: what TakeItBack's cube and RememberColor3's cubes all have
    targets = json.loads((out / "pointer_targets.json").read_text())
    assert {target for prompt, target in targets.items() if "started" in prompt} <= {"cube", None}


def test_a_perception_head_that_reads_the_hand_across_tasks_and_its_error_per_task(datasets, tmp_path):
    """A controller over two tasks whose perception head reads the hand's pose, and the perception script reading its
    error per task on the finetune's training episodes."""
    import sys

    out = tmp_path / "ckpt"
    result = CliRunner().invoke(main, ["finetune", str(datasets[COLOUR]), str(datasets[SHAPE]), "--tasks",
                                       f"{COLOUR},{SHAPE}", "--set", "model.perception_state=true", "--out", str(out), "--set", "training.steps=5",
                                       *SMALL])
    assert result.exit_code == 0, result.output
    policy = make_controller(f"learned:{out}", SHAPE).policy
    assert policy.config.perception_state and policy.perception[0].in_features == 2 * 8 + len(proprio_names())
    script = [sys.executable, str(REPO / "scripts" / "perception_error.py"), str(out), str(datasets[COLOUR]),
              str(datasets[SHAPE]), "--tasks", f"{COLOUR},{SHAPE}", "--split", "training", "--frames", "40"]
    run = subprocess.run(script, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert "of the finetune's training episodes" in run.stdout
    rows = [line.split("|") for line in run.stdout.splitlines() if line.startswith((f"| {COLOUR} |", f"| {SHAPE} |"))]
    assert len(rows) == 2 and all(int(row[2]) > 0 for row in rows)  # both tasks' frames found, by their layouts
    one = subprocess.run([*script[:3], str(datasets[SHAPE]), "--tasks", SHAPE, "--split", "all", "--frames", "40"],
                         capture_output=True, text=True, timeout=600)  # one of its tasks: the other's entries unknown
    assert one.returncode == 0, one.stderr
    (row,) = [line.split("|") for line in one.stdout.splitlines() if line.startswith(f"| {SHAPE} |")]
    assert int(row[2]) > 0 and f"| {COLOUR} |" not in one.stdout
    assert "| cube_red_x |" not in one.stdout and "| cube_red |" not in one.stdout


def test_a_controller_on_the_harness_proprio_plays_the_benchmark_as_a_protocol_entry(datasets, tmp_path):
    """``state=harness``: the policy reads the harness's seven proprioception numbers (derived from the
    demonstrations' hand and fingers), its perception head none of the robot's own readings; in the benchmark it gets
    the policy side's view alone (the guard would stop any read of the simulator) and its table is a protocol entry."""
    out = tmp_path / "ckpt"
    result = CliRunner().invoke(main, ["finetune", str(datasets[COLOUR]), str(datasets[SHAPE]), "--tasks",
                                       f"{COLOUR},{SHAPE}", "--set", "state=harness", "--out", str(out), "--set",
                                       "training.steps=5", *SMALL])
    assert result.exit_code == 0, result.output
    controller = make_controller(f"learned:{out}", COLOUR)
    config = controller.policy.config
    assert config.state_names == HARNESS_PROPRIO_NAMES and controller.spec.harness_inputs
    assert not set(config.perceived_names) & (set(proprio_names()) | set(HARNESS_PROPRIO_NAMES))
    assert {"cube_red_x", "shape_sphere_x"} <= set(config.perceived_names)
    assert not make_controller(f"learned:{datasets_policy(datasets, tmp_path)}", COLOUR).spec.harness_inputs
    table = tmp_path / "table"
    result = CliRunner().invoke(main, ["benchmark", "mikasa", "--tasks", COLOUR, "--controller", f"learned:{out}",
                                       "--conditions", "oracle", "--episodes", "1", "--workers", "1", "--out",
                                       str(table), "--no-progress"])
    assert result.exit_code == 0, result.output
    content = json.loads((table / "results.json").read_text())
    record = content["tasks"][COLOUR]["controller"]
    assert not content["privileged_upper_bound"] and not record["privileged"]
    assert record["reads"].startswith("the harness's inputs alone")
    assert "error" not in (table / "episodes.jsonl").read_text()


def datasets_policy(datasets, tmp_path):
    """A camera policy on the robot's joints, velocities and hand pose (``state=proprio``): beyond the harness's."""
    out = tmp_path / "proprio"
    result = CliRunner().invoke(main, ["finetune", str(datasets[COLOUR]), "--task", COLOUR, "--out", str(out),
                                       "--set", "state=proprio", "--set", "training.steps=2", *SMALL])
    assert result.exit_code == 0, result.output
    return out
