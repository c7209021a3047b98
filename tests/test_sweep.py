"""sb3_memret.analysis.sweep: a seed sweep's rows from run folders (when retrieval was learned, whether it held from
the run's middle on), its table and its figure."""

import json

import pytest

from sb3_memret.analysis.sweep import is_run, plot_sweep, run_row, sweep_table


def fake_run(folder, seed, greedy, sampled=0.9, entropy=0.3, success=0.9, minutes=7.0, baselines=None):
    """A run folder as ``train`` leaves it, as far as the sweep reads: an evaluation every 5 rounds; ``baselines``
    (condition: success) as its report records them."""
    folder.mkdir(parents=True)
    rows = [{"round": 5 * i, "timesteps": 640 * i, "episodes": 8, "greedy_accuracy": g, "sampled_fraction": sampled,
             "entropy": entropy, "success": {"overall": success}} for i, g in enumerate(greedy)]
    (folder / "evaluations.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    summary = {"seed": seed, "wall_seconds": minutes * 60}
    if baselines:
        summary["baselines"] = {name: {"success": {"overall": value}} for name, value in baselines.items()}
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


def test_a_row_says_when_retrieval_was_learned_and_whether_it_held_from_the_middle_on(tmp_path):
    steady = run_row(fake_run(tmp_path / "seed0", 0, [0.1, 0.97, 1.0, 1.0, 0.98, 1.0]))
    assert (steady["first_mastered"], steady["mastered_decisions"]) == (5, 640)
    assert steady["held"] and steady["held_from_middle"] and steady["lowest_from_middle"] == 0.98
    assert (steady["evaluations"], steady["round"], steady["seed"]) == (6, 25, 0)
    # a dip before the middle (round 12.5) breaks "held" but not "from the middle on"; one after it breaks both
    early_dip = run_row(fake_run(tmp_path / "seed1", 1, [0.1, 0.97, 0.90, 1.0, 1.0, 1.0]))
    assert not early_dip["held"] and early_dip["held_from_middle"]
    late_dip = run_row(fake_run(tmp_path / "seed2", 2, [0.1, 0.97, 1.0, 0.94, 1.0, 1.0]))
    assert not late_dip["held_from_middle"] and late_dip["lowest_from_middle"] == 0.94
    never = run_row(fake_run(tmp_path / "seed3", 3, [0.1, 0.5, 0.9]))
    assert never["first_mastered"] != never["first_mastered"] and not never["held"]  # NaN


def test_the_table_has_a_row_per_run_and_their_mean(tmp_path):
    rows = [run_row(fake_run(tmp_path / f"seed{s}", s, [0.1, 1.0, 1.0], success=s / 4)) for s in range(3)]
    lines = sweep_table(rows, oracle=0.5)
    assert len(lines) == 2 + 3 + 1 and lines[-1].startswith("| mean ± std |")
    assert "| seed2 | 2 | 3 | 5 (640) | yes | yes (100%) |" in lines[4] and "| 1.00 |" in lines[4]  # 0.5 / 0.5
    assert "3 of 3" in lines[-1] and "25% ± 20%" in lines[-1]
    assert "recall / oracle" not in sweep_table(rows)[0]
    # a run whose report played the baselines is set over its own oracle, and shows its no-memory success
    own = run_row(fake_run(tmp_path / "seed9", 9, [0.1, 1.0, 1.0], success=0.9, baselines={"oracle": 0.95, "none": 0.2}))
    assert (own["oracle"], own["none"]) == (0.95, 0.2)
    line = sweep_table([own], oracle=0.5)[2]
    assert "| 90% | 95% | 20% | 0.95 |" in line


def test_only_finished_runs_count_and_the_figure_is_drawn(tmp_path):
    runs = [fake_run(tmp_path / f"seed{s}", s, [0.2, 1.0]) for s in range(2)]
    (tmp_path / "unfinished").mkdir()
    assert [is_run(folder) for folder in (*runs, tmp_path / "unfinished")] == [True, True, False]
    with pytest.raises(ValueError, match="not a training run"):
        run_row(tmp_path / "unfinished")
    assert plot_sweep(runs, tmp_path / "sweep.png").stat().st_size > 10_000
