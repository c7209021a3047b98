import json

from click.testing import CliRunner

from sb3_memret.cli import main


def test_every_command_has_help():
    runner = CliRunner()
    for args in ([], ["rollout"], ["train"], ["eval"]):
        result = runner.invoke(main, [*args, "--help"])
        assert result.exit_code == 0 and "Usage" in result.output


def test_rollout_json():
    result = CliRunner().invoke(main, ["rollout", "--episodes", "1", "--layer", "1", "--json"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout.strip().splitlines()[-1])
    assert payload["condition"] == "oracle" and payload["episodes"] == 1
    assert set(payload["success"]) == {"1", "overall"}
    assert payload["success"]["1"] == 1.0


def test_bad_options_give_clear_errors():
    runner = CliRunner()
    result = runner.invoke(main, ["rollout", "--condition", "maybe"])
    assert result.exit_code == 2 and "'maybe' is not one of 'oracle', 'none', 'wrong'" in result.output
    result = runner.invoke(main, ["rollout", "--controller", "pi0"])
    assert result.exit_code == 2 and "unknown controller 'pi0'" in result.output
    result = runner.invoke(main, ["rollout", "--layer", "4"])
    assert result.exit_code == 2 and "--layer" in result.output
