"""``scripts/`` holds the benchmarks a user runs: each imports and answers ``--help`` with what it measures (its
docstring), without running anything; the probes of one study live in ``lab/``."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

SCRIPTS = sorted((Path(__file__).resolve().parents[1] / "scripts").glob("*.py"))


def test_scripts_holds_benchmarks_and_tools_not_probes():
    names = {path.stem for path in SCRIPTS}
    assert {"bench_main_job", "bench_vec_env", "seed_sweep"} <= names
    assert not names & {"mikasa_probe", "touch_diagnosis", "probe_camera_features"}  # studies: lab/


@pytest.mark.parametrize("path", SCRIPTS, ids=[path.stem for path in SCRIPTS])
def test_every_script_answers_help_with_what_it_measures(path, load_script, monkeypatch, capsys):
    doc = ast.get_docstring(ast.parse(path.read_text()))
    assert doc, f"{path.name} has no docstring saying what it measures"
    module = load_script(path.stem)
    monkeypatch.setattr(sys, "argv", [str(path), "--help"])
    with pytest.raises(SystemExit) as stopped:
        module.main()
    assert stopped.value.code == 0
    assert "usage:" in capsys.readouterr().out


def test_the_timescale_comparison_s_paired_test_is_mcnemar_s_exact_one(load_script):
    p = load_script("compare_timescales").mcnemar_p
    assert p(0, 0) == 1.0 and p(3, 3) == 1.0
    assert p(6, 0) == p(0, 6) == 2 / 64  # six discordant pairs all one way
    assert p(9, 1) == 2 * (1 + 10) / 1024
