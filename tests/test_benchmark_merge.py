"""``benchmark merge``: tables played apart joined into one, each episode once, only of one protocol."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from sb3_memret.benchmark.runner import EPISODES_FILE, PROTOCOL_FILE, Plan, Protocol, plan, results
from sb3_memret.cli import main

TASK = "RememberColor3-VLA-v0"


def _folder(path: Path, run: Plan, records: list[dict]) -> Path:
    """A run folder as `benchmark mikasa` leaves it: its protocol, its episode log and its results."""
    path.mkdir(parents=True)
    (path / PROTOCOL_FILE).write_text(json.dumps(run.protocol.to_json()))
    (path / EPISODES_FILE).write_text("".join(json.dumps(r) + "\n" for r in records))
    (path / "results.json").write_text(json.dumps(results(run, records)))
    return path


def _episode(run: Plan, condition: str, seed: int, success: bool, **changed) -> dict:
    return {"env_id": TASK, "condition": condition, "seed": seed, "success": success, "return": 1.0, "steps": 9,
            "controller_sha256": run.controllers[TASK]["sha256"], "task_sha256": run.task_digests[TASK], **changed}


def test_merge_adds_the_episodes_a_table_lacks_once_and_only_current_ones(tmp_path):
    from sb3_memret.benchmark.merge import merge_runs

    protocol = Protocol(seed_set="dev", episodes=2)
    first, second = protocol.seeds()
    mine = plan(protocol, ["none", "oracle"], env_ids=[TASK])
    theirs = plan(protocol, ["oracle", "wrong"], env_ids=[TASK])
    into = _folder(tmp_path / "into", mine, [_episode(mine, "none", first, False),
                                              _episode(mine, "oracle", first, True)])
    source = _folder(tmp_path / "source", theirs, [
        _episode(theirs, "oracle", first, False),  # into has this unit already: never twice
        _episode(theirs, "oracle", second, True),
        _episode(theirs, "wrong", first, False),
        _episode(theirs, "wrong", second, False, controller_sha256="another controller"),  # not counted here
        {**_episode(theirs, "wrong", second, False), "error": "RuntimeError"}])
    elsewhere = merge_runs([source], into, only=["RememberColor5-VLA-v0"])  # another task's only: nothing of these
    assert elsewhere.added == {} and list(elsewhere.content["tasks"]) == [TASK]
    merged = merge_runs([source], into)
    assert merged.added == {(TASK, "oracle"): 1, (TASK, "wrong"): 1} and merged.left_out == {str(source): 1}
    cells = merged.content["tasks"][TASK]["conditions"]
    assert merged.content["protocol"]["conditions"] == ["none", "oracle", "wrong"]
    assert cells["oracle"]["successes"] == [True, True] and cells["oracle"]["complete"]  # its own first episode kept
    assert cells["wrong"]["episodes"] == 1 and not cells["wrong"]["complete"]
    assert cells["none"]["episodes"] == 1
    logged = (into / EPISODES_FILE).read_text().splitlines()
    assert len(logged) == 4
    again = merge_runs([source], into)  # nothing new the second time
    assert again.added == {} and len((into / EPISODES_FILE).read_text().splitlines()) == 4


def test_merge_refuses_another_protocol_itself_and_a_folder_that_is_no_run(tmp_path):
    from sb3_memret.benchmark.merge import merge_runs

    run = plan(Protocol(seed_set="dev", episodes=2), ["oracle"], env_ids=[TASK])
    other = plan(Protocol(seed_set="dev", episodes=3), ["oracle"], env_ids=[TASK])
    into = _folder(tmp_path / "into", run, [])
    longer = _folder(tmp_path / "longer", other, [])
    with pytest.raises(ValueError, match="another protocol.*episodes: 3 against 2"):
        merge_runs([longer], into)
    with pytest.raises(ValueError, match="is the folder merged into"):
        merge_runs([into], into)
    (tmp_path / "empty").mkdir()
    result = CliRunner().invoke(main, ["benchmark", "merge", str(tmp_path / "empty"), "--into", str(into)])
    assert result.exit_code == 2 and "has no protocol.json" in result.output and "Traceback" not in result.output


def test_merge_command_writes_the_report_and_says_what_it_added(tmp_path):
    protocol = Protocol(seed_set="dev", episodes=1)
    run = plan(protocol, ["oracle"], env_ids=[TASK])
    into = _folder(tmp_path / "into", run, [])
    source = _folder(tmp_path / "source", run, [_episode(run, "oracle", protocol.seeds()[0], True)])
    both = CliRunner().invoke(main, ["benchmark", "merge", str(source), "--into", str(into), "--split", "short",
                                     "--tasks", TASK])
    assert both.exit_code == 2 and "not both" in both.output
    result = CliRunner().invoke(main, ["benchmark", "merge", str(source), "--into", str(into), "--split", "short"])
    assert result.exit_code == 0, result.output
    assert f"added 1 oracle episodes of {TASK}" in result.output and (into / "report.md").is_file()
    assert "100%" in (into / "report.md").read_text()
