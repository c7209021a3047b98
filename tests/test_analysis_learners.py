"""sb3_memret.analysis.learners: a learners folder's index and its table, a row a task (trained, training or not
started), each trained run's figures and how it ended."""

import json

import pytest

from sb3_memret.analysis.learners import (LEARNERS_FILE, is_learners_folder, learner_rows, learners_table,
                                          record_tasks)


def fake_learner(folder, greedy, stopped=None, interrupted=False, minutes=3.0):
    """A task's run folder as ``train`` leaves it, as far as the table reads: an evaluation every 5 rounds."""
    folder.mkdir(parents=True)
    rows = [{"round": 5 * i, "timesteps": 640 * i, "episodes": 20, "greedy_accuracy": g, "sampled_fraction": g,
             "entropy": 0.5, "success": {"overall": g}} for i, g in enumerate(greedy)]
    (folder / "evaluations.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    (folder / "summary.json").write_text(json.dumps({
        "seed": 0, "wall_seconds": minutes * 60, "num_timesteps": 640 * (len(greedy) - 1), "controller": "scripted",
        "stopped_at_target_round": stopped, "interrupted": interrupted}))


def test_the_index_keeps_the_tasks_asked_in_order_across_commands(tmp_path):
    assert not is_learners_folder(tmp_path)
    assert record_tasks(tmp_path / "learners", ["B-VLA-v0", "A-VLA-v0"]) == ["B-VLA-v0", "A-VLA-v0"]
    assert record_tasks(tmp_path / "learners", ["A-VLA-v0", "C-VLA-v0"]) == ["B-VLA-v0", "A-VLA-v0", "C-VLA-v0"]
    assert is_learners_folder(tmp_path / "learners")
    assert json.loads((tmp_path / "learners" / LEARNERS_FILE).read_text())["tasks"][-1] == "C-VLA-v0"


def test_a_row_a_task_with_how_each_run_ended(tmp_path):
    folder = tmp_path / "learners"
    record_tasks(folder, ["Stopped-VLA-v0", "Budget-VLA-v0", "Cut-VLA-v0", "Training-VLA-v0", "Later-VLA-v0"])
    fake_learner(folder / "Stopped-VLA-v0", [0.0, 1.0, 1.0], stopped=10)
    fake_learner(folder / "Budget-VLA-v0", [0.0, 0.5, 0.9])
    fake_learner(folder / "Cut-VLA-v0", [0.0, 0.2], interrupted=True)
    (folder / "Training-VLA-v0").mkdir()  # a run under way: no summary yet
    rows = learner_rows(folder)
    assert [row["state"] for row in rows] == ["trained"] * 3 + ["training", "not started"]
    assert [row.get("ended") for row in rows[:3]] == ["stopped at round 10: greedy at the target", "its budget",
                                                       "interrupted"]
    assert (rows[0]["first_mastered"], rows[0]["decisions"], rows[0]["greedy"]) == (5, 1280, 1.0)
    lines = learners_table(rows)
    assert len(lines) == 2 + 5 + 2
    assert lines[2] == ("| Stopped-VLA-v0 | 10 (1280) | stopped at round 10: greedy at the target | 5 | 20 | 100% | "
                        "100% | 100% | 3.0 |")
    assert "| never |" in lines[3] and lines[6].startswith("| Later-VLA-v0 | not started |")
    assert lines[-1].startswith("3 of 5 trained; 1 of them end at greedy retrieval ≥ 95%") and "9 minutes" in lines[-1]


def test_a_folder_without_an_index_is_refused_by_name(tmp_path):
    with pytest.raises(FileNotFoundError, match=f"{tmp_path}.*{LEARNERS_FILE}"):
        learner_rows(tmp_path)
