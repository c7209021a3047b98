import json

from click.testing import CliRunner

from sb3_memret.cli import main


def _command_paths(group, path=()):
    """Every command path under ``group`` (its subgroups' commands too), discovered rather than listed."""
    import click

    yield path
    if isinstance(group, click.Group):
        for name in group.list_commands(click.Context(group)):
            yield from _command_paths(group.get_command(click.Context(group), name), (*path, name))


def test_every_command_has_help():
    """Every command and subcommand, found by walking the CLI, answers --help with its usage and a description."""
    runner = CliRunner()
    paths = list(_command_paths(main))
    assert {("serve",), ("benchmark",), ("train",), ("finetune",)} <= set(paths) and len(paths) > 15
    for args in paths:
        result = runner.invoke(main, [*args, "--help"])
        assert result.exit_code == 0 and "Usage" in result.output, (args, result.output)
        described = result.output.split("Options:")[0].split("\n", 2)[-1].strip()
        assert described, f"sb3-memret {' '.join(args)} --help says nothing of what it does"


def test_help_and_argument_errors_load_no_heavy_library():
    """--help and a one-line argument error answer before torch, ManiSkill or lerobot load (they take seconds)."""
    import subprocess
    import sys

    code = ("import sys\n"
            "from sb3_memret.cli import main\n"
            "for args in (['--help'], ['train', '--help'], ['train', 'recall', '--n-envs', '0'], ['rollout', '--episodes', '0']):\n"
            "    try:\n"
            "        main(args)\n"
            "    except SystemExit:\n"
            "        pass\n"
            "print(sorted(m for m in ('torch', 'mani_skill', 'lerobot', 'sentence_transformers') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_rollout_json():
    result = CliRunner().invoke(main, ["rollout", "--controller", "scripted", "--episodes", "1", "--group", "1", "--json"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout.strip().splitlines()[-1])
    assert payload["condition"] == "oracle" and payload["episodes"] == 1
    assert set(payload["success"]) == {"1", "overall"}
    assert payload["success"]["1"] == 1.0


def test_every_command_that_plays_episodes_defaults_to_development_seeds():
    """A task's test set (MIKASA's protocol seeds) plays only when asked for by name, `--seeds protocol`; `rollout`
    refuses seeds of one's choosing beside it."""
    import click

    for path in (("rollout",), ("eval",), ("benchmark", "mikasa")):
        command = main
        for name in path:
            command = command.get_command(click.Context(command), name)
        (option,) = [p for p in command.params if p.name == "seed_set"]
        assert option.default == "dev" and sorted(option.type.choices) == ["dev", "protocol"], path
    result = CliRunner().invoke(main, ["rollout", "--controller", "scripted", "--seeds", "protocol", "--seed", "3"])
    assert result.exit_code == 2 and "give it or --seed, not both" in result.output


def test_bad_options_give_clear_errors():
    runner = CliRunner()
    result = runner.invoke(main, ["rollout", "--condition", "maybe"])
    assert result.exit_code == 2 and "'maybe' is not one of 'oracle', 'none', 'wrong'" in result.output
    result = runner.invoke(main, ["rollout", "--controller", "pi0"])
    assert result.exit_code == 2 and "unknown controller 'pi0'" in result.output
    result = runner.invoke(main, ["rollout", "--group", "4"])
    assert result.exit_code == 2 and "--group" in result.output and "has no layer '4' to choose; expected one of ['1', '2', '3']" in result.output


def test_ablate_refuses_intervals_the_controller_cannot_run():
    runner = CliRunner()
    result = runner.invoke(main, ["ablate", "replan", "--intervals", "8,40", "--no-progress"])
    assert result.exit_code == 2 and "must lie in [1, 32] (the controller's chunk length)" in result.output
    result = runner.invoke(main, ["ablate", "replan", "--intervals", "eight", "--no-progress"])
    assert result.exit_code == 2 and "'eight' is not a comma-separated list of integers" in result.output
    result = runner.invoke(main, ["ablate", "prompt", "--replan-every", "33", "--no-progress"])
    assert result.exit_code == 2 and "33 exceeds the controller's chunk length 32" in result.output
    result = runner.invoke(main, ["ablate", "tables"])
    assert result.exit_code == 2 and ("unknown ablation 'tables' for task 'drawer'; expected one of ['memcount', "
                                      "'prompt', 'replan', 'wording']") in result.output
    result = runner.invoke(main, ["ablate", "prompt", "--group", "5", "--no-progress"])
    assert result.exit_code == 2 and "the cube's drawer layer, one of [1, 2, 3]; got '5'" in result.output
    result = runner.invoke(main, ["ablate", "prompt", "--task", "RememberColor3-VLA-v0", "--controller", "scripted"])
    assert result.exit_code == 2 and "task 'RememberColor3-VLA-v0' defines no ablation tables" in result.output


def test_run_commands_refuse_folders_that_are_not_runs(tmp_path):
    runner = CliRunner()
    result = runner.invoke(main, ["plot", str(tmp_path)])
    assert result.exit_code == 2 and "progress.csv" in result.output and str(tmp_path.name) in result.output
    result = runner.invoke(main, ["report", str(tmp_path)])
    assert result.exit_code == 2 and "no summary.json" in result.output
    result = runner.invoke(main, ["trace", str(tmp_path)])
    assert result.exit_code == 2 and "lacks ['initial_model.zip', 'final_model.zip']" in result.output


def test_ablate_default_intervals_are_the_tasks():
    from sb3_memret.tasks.ablations import AblationOptions
    from sb3_memret.tasks.drawer import DrawerTask
    from sb3_memret.tasks.drawer.ablations import REPLAN_INTERVALS

    option = next(p for p in main.commands["ablate"].params if p.name == "intervals")
    assert option.default is None
    assert DrawerTask().ablations()["replan"](AblationOptions()).rows == tuple(map(str, REPLAN_INTERVALS))


def test_mistakes_are_one_line_without_a_traceback(tmp_path, monkeypatch):
    """What a new user trips over: a file that is not a model, a YAML typo, no CPU renderer."""
    from sb3_memret.common.rendering import RENDERER_DIR_ENV

    notes = tmp_path / "notes.txt"
    notes.write_text("not a model")
    broken = tmp_path / "broken.yml"
    broken.write_text("sb3_memret/DrawerRecall-v0:\n  n_timesteps: [128\n  n_envs: 2\n")
    monkeypatch.delenv("VK_ICD_FILENAMES", raising=False)
    monkeypatch.setenv(RENDERER_DIR_ENV, str(tmp_path / "no-renderer"))
    cases = {
        ("eval", str(notes)): f"{str(notes)!r} is not a model saved by sb3-memret",
        ("trace", str(notes)): "is not a model saved by sb3-memret",
        ("train", "recall", "--config", str(broken), "--out", str(tmp_path / "r")):
            f"{broken} is not valid YAML at line 3, column 9",
        ("rollout", "--render-backend", "cpu"): "install it with: make renderer",
        ("ablate", "replan", "--backend", "gpu", "--ray-address", "auto"):
            "--ray-address 'auto' runs the physics on Ray, so --backend must be ray (or left out), not 'gpu'",
        ("train", "recall", "--backend", "threads"): "'threads' is not one of 'auto', 'process', 'gpu', 'ray'",
    }
    for args, expected in cases.items():
        result = CliRunner().invoke(main, list(args), prog_name="sb3-memret")
        lines = result.output.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and lines[0].startswith("Error: "), result.output
        assert expected in lines[0] and f"(see: sb3-memret {args[0]} --help)" in lines[0], lines[0]
        assert result.exception is None or isinstance(result.exception, SystemExit)


def test_gpu_physics_without_a_cuda_device_is_one_line(tmp_path, monkeypatch):
    """``--backend gpu`` where torch finds no CUDA device: one line naming what is missing and what to use, no
    traceback (the machine's own CUDA is hidden, so the test means the same everywhere)."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    result = CliRunner().invoke(main, ["train", "recall", "--controller", "scripted", "--backend", "gpu", "--n-envs", "2",
                                       "--timesteps", "8", "--no-progress", "--out", str(tmp_path / "run")])
    assert result.exit_code == 1, result.output
    assert "needs a CUDA GPU" in result.output and "--backend process" in result.output
    assert "Traceback" not in result.output
