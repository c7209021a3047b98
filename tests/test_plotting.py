"""Learning curves of a run folder: what is parsed from its logs, and that the PNG really holds a plot."""

import csv
import json

import matplotlib.image
import matplotlib.pyplot as plt
import numpy as np
import pytest

from sb3_memret.analysis.plotting import learning_curves, plot_learning_curves
from test_callbacks import train_toy

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def report(round_, greedy, entropy):
    """An evaluations.jsonl row as the eval callback writes it."""
    return {"round": round_, "timesteps": 32 * round_, "greedy_accuracy": greedy, "sampled_fraction": greedy / 2,
            "entropy": entropy, "success": {"overall": greedy, "1": greedy, "2": greedy, "3": greedy}, "episodes": 8}


def write_run(folder, columns=("time/total_timesteps", "rollout/sampled_fraction", "train/entropy_loss", "eval/round")):
    """A run of 3 rounds plus the final row; ``rollout/success`` is never logged (a missing column), round 1
    evaluated twice (a resume), the first round has no entropy yet and the final row no rollout (empty cells)."""
    rows = [{"time/total_timesteps": 32, "rollout/sampled_fraction": 0.25, "train/entropy_loss": "", "eval/round": 0},
            {"time/total_timesteps": 64, "rollout/sampled_fraction": 0.5, "train/entropy_loss": -1.5, "eval/round": 1},
            {"time/total_timesteps": 96, "rollout/sampled_fraction": 0.75, "train/entropy_loss": -1, "eval/round": ""},
            {"time/total_timesteps": "", "rollout/sampled_fraction": "", "train/entropy_loss": -0.5, "eval/round": 3}]
    with open(folder / "progress.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    history = [report(0, 0.2, 1.8), report(1, 0.3, 1.6), report(1, 0.4, 1.4), report(3, 0.9, 0.5)]
    (folder / "evaluations.jsonl").write_text("".join(json.dumps(row) + "\n" for row in history))
    return folder


def test_curves_are_parsed_per_round_and_per_evaluation(tmp_path):
    curves = learning_curves(write_run(tmp_path))
    assert curves.train_round.tolist() == [0, 1, 2]
    assert curves.train_sampled_fraction.tolist() == [0.25, 0.5, 0.75]
    np.testing.assert_array_equal(curves.train_entropy, [np.nan, 1.5, 1.0])  # -entropy_loss, none before an update
    assert curves.eval_round.tolist() == [0, 1, 3]  # the re-evaluated round 1 keeps its last report
    assert curves.eval_greedy_accuracy.tolist() == [0.2, 0.4, 0.9]
    assert curves.eval_sampled_fraction.tolist() == [0.1, 0.2, 0.45]
    assert curves.eval_entropy.tolist() == [1.8, 1.4, 0.5]
    assert curves.eval_success.tolist() == [0.2, 0.4, 0.9]


def test_a_missing_column_or_file_is_an_empty_series(tmp_path):
    write_run(tmp_path, columns=("time/total_timesteps", "rollout/sampled_fraction"))
    assert np.isnan(learning_curves(tmp_path).train_entropy).all()
    (tmp_path / "progress.csv").unlink()
    curves = learning_curves(tmp_path)
    assert curves.train_round.size == curves.train_entropy.size == 0 and curves.eval_round.tolist() == [0, 1, 3]
    assert plot_learning_curves(tmp_path).exists()


def test_plot_is_a_real_png(tmp_path):
    path = plot_learning_curves(write_run(tmp_path), title="toy", chance=1 / 6)
    assert path == tmp_path / "learning_curves.png"
    assert path.read_bytes().startswith(PNG_MAGIC) and path.stat().st_size > 10_000
    rgba = (matplotlib.image.imread(path) * 255).astype(np.uint8).view(np.uint32)  # one number per pixel
    assert len(np.unique(rgba)) > 50  # lines, text and markers, not a blank canvas
    assert plt.get_fignums() == []  # no figure left open in pyplot
    out = plot_learning_curves(tmp_path, out=tmp_path / "figs" / "fig5.png")
    assert out == tmp_path / "figs" / "fig5.png" and out.exists()


def test_missing_or_empty_logs_are_errors(tmp_path):
    folder = tmp_path / "not_a_run"
    folder.mkdir()
    with pytest.raises(FileNotFoundError, match="not_a_run.*progress.csv.*evaluations.jsonl"):
        learning_curves(folder)
    (folder / "progress.csv").write_text("time/total_timesteps,rollout/sampled_fraction\n")
    (folder / "evaluations.jsonl").write_text("")
    with pytest.raises(ValueError, match="no rounds or evaluations"):
        learning_curves(folder)


def test_plot_of_a_real_training_run(tmp_path):
    train_toy(tmp_path, rounds=3)
    curves = learning_curves(tmp_path)
    assert curves.train_round.tolist() == [0, 1, 2]
    assert curves.eval_round.tolist() == [0, 1, 2, 3]
    assert np.isnan(curves.train_entropy[0]) and (curves.train_entropy[1:] > 0).all()
    assert ((0 <= curves.eval_greedy_accuracy) & (curves.eval_greedy_accuracy <= 1)).all()
    assert plot_learning_curves(tmp_path, chance=1 / 6).stat().st_size > 10_000
