"""Two benchmark runs paired episode by episode: seeds matched, disagreements counted, McNemar's exact p."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from sb3_memret.benchmark.compare import PairedCell, paired_cells, pooled, render_comparison
from sb3_memret.cli import main


def _run(tmp_path, name, cells):
    """A run folder whose results.json holds ``cells``: {env id: {condition: {seed: success}}}."""
    tasks = {env_id: {"conditions": {c: {"seeds": list(outcomes), "successes": list(outcomes.values())}
                                     for c, outcomes in conditions.items()}}
             for env_id, conditions in cells.items()}
    folder = tmp_path / name
    folder.mkdir()
    (folder / "results.json").write_text(json.dumps({"protocol": {}, "tasks": tasks}))
    return folder


def _results(folder):
    return json.loads((folder / "results.json").read_text())


def test_episodes_pair_by_seed_and_only_disagreements_count(tmp_path):
    a = _run(tmp_path, "a", {"T1": {"oracle": {1: True, 2: True, 3: False, 4: True, 9: True}},
                             "T2": {"oracle": {1: True}}, "T3": {"oracle": {1: True}}})
    b = _run(tmp_path, "b", {"T1": {"oracle": {4: False, 3: True, 2: True, 1: False}},  # seed 9 not played here
                             "T2": {"none": {1: True}}})  # T2 not under the condition, T3 not at all
    cells = paired_cells(_results(a), _results(b), "oracle", "oracle")
    assert cells == [PairedCell("T1", both=1, only_a=2, only_b=1, neither=0)]
    assert (cells[0].episodes, cells[0].a, cells[0].b) == (4, 3, 2)
    across = paired_cells(_results(a), _results(b), "oracle", "none")  # two conditions side by side
    assert [c.env_id for c in across] == ["T2"] and across[0].both == 1
    with pytest.raises(ValueError, match="'wrong'"):
        paired_cells(_results(a), _results(b), "wrong", "wrong")


def test_mcnemar_is_exact_and_pooling_counts_every_episode_once():
    seven_to_none = PairedCell("T", both=3, only_a=7, only_b=0, neither=0)
    assert seven_to_none.p_value == pytest.approx(2 * 0.5 ** 7)
    assert PairedCell("T", both=5, only_a=0, only_b=0, neither=5).p_value == 1.0  # no disagreement: no evidence
    assert PairedCell("T", both=0, only_a=3, only_b=3, neither=0).p_value == pytest.approx(1.0)
    total = pooled([seven_to_none, PairedCell("U", both=1, only_a=0, only_b=2, neither=1)])
    assert (total.episodes, total.only_a, total.only_b) == (14, 7, 2)
    table = render_comparison([seven_to_none], "one", "two")
    assert "| T | 10 | 100% (10) | 30% (3) | 7 | 0 | 0.0156 |" in table and "**all tasks**" in table


def test_the_command_compares_two_runs_and_refuses_a_folder_without_results(tmp_path):
    a = _run(tmp_path, "a", {"T1": {"oracle": {1: True, 2: False}, "recall": {1: True, 2: True}}})
    runner = CliRunner()
    result = runner.invoke(main, ["benchmark", "compare", str(a), str(a), "--condition", "recall",
                                  "--condition-b", "oracle"])
    assert result.exit_code == 0, result.output
    assert f"A: {a} (recall)" in result.output and "| T1 | 2 | 100% (2) | 50% (1) | 1 | 0 | 1 |" in result.output
    empty = tmp_path / "empty"
    empty.mkdir()
    result = runner.invoke(main, ["benchmark", "compare", str(a), str(empty)])
    assert result.exit_code == 2 and "holds no results.json" in result.output
