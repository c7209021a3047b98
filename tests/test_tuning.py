"""`sb3-memret tune`: the search space, the pruning reporter, the best config written back, and a small
study on the real simulator that an interrupted or repeated command continues."""

import csv

import optuna
import pytest
from click.testing import CliRunner

from sb3_memret.evaluation.retrieval import RetrievalReport
from sb3_memret.cli import main
from sb3_memret.training.config import load_config, parse_section
from sb3_memret.training.tuning import TrialReporter, apply_hyperparameters, sample_hyperparameters
from tiny_run import TINY as TINY_RUN

BASE = parse_section({"n_timesteps": 64, "n_envs": 2, "n_steps": 16, "policy_kwargs": {"hidden": 64},
                      "env_kwargs": {"capacity": 6}}, "sb3_memret/DrawerRecall-v0")
TINY = TINY_RUN.replace("n_timesteps: 32", "n_timesteps: 16")  # one round a trial


def test_a_sampled_point_is_a_valid_zoo_section_that_keeps_what_the_search_does_not_vary():
    for seed in range(20):
        trial = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=seed)).ask()
        params = sample_hyperparameters(trial, n_envs=2)
        config = apply_hyperparameters(BASE, params)
        assert config.ppo["batch_size"] <= config.ppo["n_steps"] * 2
        assert config.n_timesteps == 64 and config.env_kwargs == {"capacity": 6}
        assert config.policy_kwargs["hidden"] == 64  # kept beside the sampled policy keys
        assert config.policy_kwargs["exploration"] in ("decision", "episode")


def test_hyperparameters_out_of_range_are_refused():
    with pytest.raises(ValueError, match="learning_rate=-1"):
        apply_hyperparameters(BASE, {"learning_rate": -1})
    with pytest.raises(ValueError, match="unknown key 'warmup'"):
        apply_hyperparameters(BASE, {"policy_kwargs": {"warmup": 3}})


def report(accuracy):
    return RetrievalReport(episodes=4, decisions=10, greedy_accuracy=accuracy, sampled_fraction=0.5, entropy=1.0,
                           success={"overall": 0.5})


def test_the_reporter_reports_the_running_mean_per_round_and_prunes_when_told():
    class Trial:
        def __init__(self, prune_after):
            self.reports, self.prune_after = [], prune_after

        def report(self, value, step):
            self.reports.append((step, value))

        def should_prune(self):
            return len(self.reports) >= self.prune_after

    trial = Trial(prune_after=3)
    reporter = TrialReporter(trial)
    for round_, accuracy in ((0, 0.2), (2, 0.6)):
        reporter.evaluation_started(round_, 4)
        reporter.evaluation_finished(report(accuracy))
    assert trial.reports == [(0, 0.2), (2, pytest.approx(0.4))]
    reporter.evaluation_finished(None)  # a failed evaluation reports nothing
    reporter.evaluation_started(4, 4)
    with pytest.raises(optuna.TrialPruned, match="round 4"):
        reporter.evaluation_finished(report(1.0))


def test_tune_runs_a_study_writes_the_best_config_and_continues_it(tmp_path):
    config = tmp_path / "tiny.yml"
    config.write_text(TINY)
    out = tmp_path / "study"
    args = ["tune", "recall", "--config", str(config), "--controller", "scripted", "--eval-episodes", "1",
            "--eval-every", "1", "--startup-trials", "1", "--out", str(out)]
    result = CliRunner().invoke(main, [*args, "--trials", "2"])
    assert result.exit_code == 0, result.output
    with open(out / "trials.csv") as f:
        trials = list(csv.DictReader(f))
    assert [t["number"] for t in trials] == ["0", "1"] and all(t["state"] == "COMPLETE" for t in trials)
    assert (out / "trial-0" / "evaluations.jsonl").exists() and (out / "trial-1" / "final_model.zip").exists()
    best = load_config(out / "best_config.yml", "sb3_memret/DrawerRecall-v0")
    assert best.env_kwargs["max_control_steps"] == 48 and best.n_timesteps == 16
    chosen = max(trials, key=lambda t: float(t["objective"]))
    assert best.ppo["learning_rate"] == pytest.approx(float(chosen["learning_rate"]))
    result = CliRunner().invoke(main, [*args, "--trials", "1"])
    assert result.exit_code == 0, result.output
    with open(out / "trials.csv") as f:
        assert [t["number"] for t in csv.DictReader(f)] == ["0", "1", "2"]
