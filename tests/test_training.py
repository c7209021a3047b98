"""End to end on the real simulator: `sb3-memret train recall` runs, logs every metric, is
interrupted and resumed from its checkpoint, and `sb3-memret eval` scores the result."""

import csv
import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from stable_baselines3 import PPO

from sb3_memret.callbacks import RolloutRetrievalCallback, latest_checkpoint
from sb3_memret.cli import main
from sb3_memret.training.config import parse_section
from sb3_memret.training.run import RunOptions, read_history, train
from tiny_run import TINY

ZOO = Path(__file__).resolve().parents[1] / "zoo_configs"
METRICS = ["eval/greedy_accuracy", "eval/sampled_fraction", "eval/entropy", "eval/success", "eval/mean_return",
           "eval/mean_reward", "eval/true_evicted_rate", "rollout/sampled_fraction", "rollout/success",
           "rollout/true_evicted_rate", "rollout/mean_reward", "train/raw_advantage_std", "train/entropy_loss"]


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("runs")
    config = folder / "tiny.yml"
    # the evaluations the config asks for: 2 episodes each, 1 for the untrained learner's at round 0, 3 at the end
    config.write_text(TINY + "  eval_episodes: 2\n  eval_every: 1\n  initial_eval_episodes: 1\n"
                      "  final_eval_episodes: 3\n")
    out = folder / "run"
    result = cli("train", "recall", "--config", config, "--out", out, "--no-progress", "--report")
    assert result.exit_code == 0, result.output
    return out, config, result.output


def rows(out):
    with open(out / "progress.csv") as f:
        return list(csv.DictReader(f))


def test_train_writes_a_complete_run(run):
    out, _, output = run
    for name in ("config.yml", "initial_model.zip", "final_model.zip", "best_model.zip", "evaluations.jsonl", "summary.json"):
        assert (out / name).exists(), name
    assert any((out / "tensorboard").iterdir())
    assert latest_checkpoint(out / "checkpoints").name == "memret_32_steps.zip"
    logged = rows(out)
    for metric in METRICS:
        assert any(row.get(metric, "") != "" for row in logged), metric
    assert [r["round"] for r in read_history(out)] == [0, 1, 2]
    assert "| round | decisions | greedy acc." in output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["num_timesteps"] == 32 and summary["rounds"] == 2 and not summary["interrupted"]
    assert summary["eval_episodes"] == 2 and summary["initial_eval_episodes"] == 1
    assert summary["final_eval_episodes"] == 3
    assert [r["episodes"] for r in read_history(out)] == [1, 2, 3]
    # where the time went: each phase measured, the evaluations' part per round, the report's beside training's
    seconds = summary["seconds"]
    assert min(seconds[k] for k in ("setup", "collect", "update", "evaluate")) > 0
    assert list(seconds["evaluate_by_round"]) == ["0", "1", "2"]
    assert seconds["evaluate"] == pytest.approx(sum(seconds["evaluate_by_round"].values()))
    assert seconds["collect"] + seconds["update"] + seconds["evaluate"] <= seconds["learn"] + 1e-6
    assert set(seconds["report"]) == {"plot", "oracle", "none", "trace"}
    assert summary["controller"] == "learned"  # the drawer's default: the camera controller
    model = PPO.load(out / "final_model.zip")  # plain SB3 restores it
    assert model.num_timesteps == 32
    # --report: the report, its baselines played on the run's held-out workers, on the final evaluation's episodes
    assert f"report: {out / 'report.md'}" in output
    report = (out / "report.md").read_text()
    assert "2 episodes per evaluation (1 at round 0, the untrained learner's; 3 at round 2, the final one)" in report
    assert "| oracle | the instruction + the true memory | 3 |" in report and "| none | the bare instruction | 3 |" in report


def test_the_main_job_benchmark_splits_a_runs_wall_time_by_phase(run, load_script):
    """scripts/bench_main_job.py: every recorded phase of the run, its evaluations' sum, the process's start-up and
    exit as what is left of the wall time, and each phase's ratio to a baseline's."""
    out, _, _ = run
    bench = load_script("bench_main_job")
    phases = bench.split(out, wall=1000.0)
    summary = json.loads((out / "summary.json").read_text())
    assert phases["training decisions (32)"] == summary["seconds"]["collect"]
    assert phases["held-out evaluations, all (3)"] == pytest.approx(
        sum(v for k, v in phases.items() if k.startswith("held-out evaluation, round")))
    assert {"report: oracle", "report: none", "report: trace", "report: plot"} <= set(phases)
    parts = sum(v for k, v in phases.items() if not k.startswith(("held-out evaluations, all", "start-up", "total",
                                                                    "decisions/s")))
    assert phases["start-up and exit (imports, weights, MiniLM)"] == pytest.approx(1000.0 - parts)
    assert phases["decisions/s while training"] > 0
    half = {key: value / 2 for key, value in phases.items()}
    import contextlib
    import io
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        bench.print_split("job", phases, half)
    assert printed.getvalue().count("2.00x the baseline's") == len(phases) - 3  # the rounds' own lines have no pair


def test_a_report_across_tasks_is_refused_before_training():
    result = cli("train", "recall", "--tasks", "drawer,RememberColor3-VLA-v0", "--report")
    assert result.exit_code == 2 and "--report writes one task's report" in result.output


def test_resume_continues_the_same_run(run):
    out, config, _ = run
    before = len(rows(out))
    result = cli("train", "recall", "--out", out, "--resume", "--timesteps", 48, "--eval-episodes", 2, "--eval-every", 1, "--no-progress")
    assert result.exit_code == 0, result.output
    assert json.loads((out / "summary.json").read_text())["num_timesteps"] == 48
    assert len(rows(out)) > before  # appended, not overwritten
    assert [r["round"] for r in read_history(out)] == [0, 1, 2, 3]
    assert latest_checkpoint(out / "checkpoints").name == "memret_48_steps.zip"


def test_a_resume_keeps_the_controller_its_run_recorded_at_start(run, tmp_path):
    """A run killed before it finished (no summary.json) still resumes with its own controller, from run.json; a run
    that records none is refused rather than served the task's default."""
    import shutil

    import click

    from sb3_memret.cli.options import run_controller

    out, _, _ = run
    assert json.loads((out / "run.json").read_text()) == {"controller": "learned", "seed": 0,
                                                          "render_backend": "cpu"}
    killed = tmp_path / "killed"
    shutil.copytree(out, killed)
    (killed / "summary.json").unlink()
    assert run_controller(killed, "drawer", default="scripted") == "learned"
    with pytest.raises(ValueError, match="was trained with controller 'learned', not 'scripted'"):
        train(None, RunOptions(out=killed, controller="scripted", resume=True))
    (killed / "run.json").unlink()
    with pytest.raises(click.UsageError, match="records no controller .* pass --controller"):
        run_controller(killed, "drawer")
    result = cli("train", "recall", "--out", killed, "--resume", "--no-progress")
    assert result.exit_code == 2 and "records no controller" in result.output
    assert run_controller(tmp_path, "drawer", default="scripted") == "scripted"  # no run there: the default


def test_eval_command_reports_success_and_accuracy(run):
    out, _, _ = run
    result = cli("eval", out / "final_model.zip", "--episodes", 2, "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["condition"] == "recall" and report["episodes"] == 2
    assert 0.0 <= report["greedy_accuracy"] <= 1.0 and "overall" in report["success"]
    table = cli("eval", out / "final_model.zip", "--episodes", 1, "--condition", "oracle")
    assert table.exit_code == 0 and "greedy retrieval accuracy" in table.output and "| overall | 1 |" in table.output


def test_plot_trace_ablate_and_report_of_a_run(run):
    out, _, _ = run
    result = cli("plot", out)
    assert result.exit_code == 0, result.output
    png = out / "learning_curves.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000

    result = cli("trace", out, "--json")
    assert result.exit_code == 0, result.output
    before, after = json.loads(result.stdout.strip().splitlines()[-1])
    assert before["label"] == "initial_model.zip (round 0)" and after["label"].startswith("final_model.zip (round ")
    for trace in (before, after):
        (true_row,) = [row for row in trace["rows"] if row["true"]]
        assert true_row["text"] == f"the cube is in drawer layer {trace['group']}."
    assert sorted(r["text"] for r in before["rows"]) == sorted(r["text"] for r in after["rows"])  # the same bank
    text = cli("trace", out).output
    assert "C the cube is in drawer layer" in text and "retriever top-1 =" in text

    result = cli("ablate", "prompt", "--episodes", 1, "--n-envs", 1, "--no-progress", "--out", out / "ablations")
    assert result.exit_code == 0, result.output
    assert {p.name for p in (out / "ablations").iterdir()} == {"prompt.md", "prompt.csv", "prompt.json"}

    result = cli("report", out, "--baseline-episodes", 1, "--n-envs", 1)
    assert result.exit_code == 0, result.output
    report = (out / "report.md").read_text()
    for heading in ("# Training report: run", "**What was learned**", "## Held-out evaluations during training",
                    "## Final policy against the baselines", "## Introspection trace", "## Controller ablations",
                    "## Configuration", "## Reproduce"):
        assert heading in report, heading
    assert "![learning curves](learning_curves.png)" in report
    assert "| oracle | the instruction + the true memory | 1 |" in report and "| none | the bare instruction | 1 |" in report
    assert "initial_model.zip (round 0)" in report and "**Prompt ablation: cube in drawer layer 2**" in report
    history_rows = [line for line in report.splitlines() if line.startswith("| ") and line[2].isdigit()]
    assert len(history_rows) == len(read_history(out))
    assert "n_steps: 16" in report  # the run's own configuration


def test_interrupt_saves_a_checkpoint_that_resumes(tmp_path, monkeypatch):
    config = parse_section({"n_timesteps": 48, "n_envs": 1, "n_steps": 16, "batch_size": 8, "n_epochs": 1,
                            "env_kwargs": {"max_control_steps": 48}}, "sb3_memret/DrawerRecall-v0")
    options = RunOptions(out=tmp_path / "run", eval_episodes=1, eval_every=1, log_formats=("csv",))
    original = RolloutRetrievalCallback._on_step
    calls = {"n": 0}

    def ctrl_c_on_the_20th_decision(self):
        calls["n"] += 1
        if calls["n"] == 20:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(RolloutRetrievalCallback, "_on_step", ctrl_c_on_the_20th_decision)
    result = train(config, options)
    assert result.interrupted and result.num_timesteps == 20
    assert latest_checkpoint(tmp_path / "run" / "checkpoints").name == "memret_20_steps.zip"
    monkeypatch.setattr(RolloutRetrievalCallback, "_on_step", original)
    resumed = train(None, RunOptions(out=tmp_path / "run", resume=True, eval_episodes=1, log_formats=("csv",)))
    assert not resumed.interrupted and resumed.num_timesteps >= 48


def test_a_run_can_start_from_another_runs_retriever(run, tmp_path):
    out, config, _ = run
    source = PPO.load(out / "final_model.zip")
    result = cli("train", "recall", "--config", config, "--out", tmp_path / "warm", "--retriever-from",
                 out / "final_model.zip", "--timesteps", 16, "--eval-episodes", 1, "--no-progress")
    assert result.exit_code == 0, result.output
    start = PPO.load(tmp_path / "warm" / "initial_model.zip")
    for key, value in source.policy.retriever.state_dict().items():
        assert start.policy.retriever.state_dict()[key].equal(value), key
    assert json.loads((tmp_path / "warm" / "summary.json").read_text())["retriever_from"] == str(out / "final_model.zip")
    resumed = cli("train", "recall", "--out", out, "--resume", "--retriever-from", out / "final_model.zip", "--no-progress")
    assert resumed.exit_code == 2 and "--retriever-from starts a new run" in resumed.output
    set_config = tmp_path / "set.yml"
    set_config.write_text(TINY + "  policy_kwargs:\n    retriever: set\n")
    mismatch = cli("train", "recall", "--config", set_config, "--out", tmp_path / "set", "--retriever-from",
                   out / "final_model.zip", "--no-progress")
    assert mismatch.exit_code == 2 and "holds a 'mlp' retriever" in mismatch.output
    assert not (tmp_path / "set").exists()  # refused before the run folder was made


def test_run_folder_mistakes_are_refused(run, tmp_path):
    out, config, _ = run
    again = cli("train", "recall", "--config", config, "--out", out, "--no-progress")
    assert again.exit_code == 2 and "already holds a run; pass --resume" in again.output
    empty = cli("train", "recall", "--out", tmp_path / "nothing", "--resume", "--no-progress")
    assert empty.exit_code == 2 and "no checkpoint" in empty.output
    bad = tmp_path / "bad.yml"
    bad.write_text(TINY.replace("n_epochs: 2", "n_epoch: 2"))
    result = cli("train", "recall", "--config", bad, "--out", tmp_path / "x", "--no-progress")
    assert result.exit_code == 2 and "unknown key 'n_epoch'" in result.output


@pytest.mark.slow
def test_retrieval_is_learned_on_the_real_simulator():
    """The default config's ten rounds from random initialisation, on the scripted controller: the greedy
    retriever picks the true cube memory and the sampling policy has moved well away from chance."""
    from sb3_memret.training.config import load_task_config
    from sb3_memret.envs.vec_env import make_recall_vec_env
    from sb3_memret.evaluation.retrieval import evaluate_retrieval
    from sb3_memret.policy.policy import MemoryRetrievalPolicy
    from sb3_memret.policy.ppo import MemRetPPO
    from sb3_memret.training.run import env_kwargs_for

    config = load_task_config("drawer")
    kwargs = env_kwargs_for(config, "scripted")
    venv = make_recall_vec_env(config.n_envs, kwargs, seed=0)
    held_out = make_recall_vec_env(config.n_envs, kwargs)
    try:
        model = MemRetPPO(MemoryRetrievalPolicy, venv, seed=0, **config.algo_kwargs())
        before = evaluate_retrieval(model, held_out, 6, seed=1_000_000)
        model.learn(10 * config.n_envs * config.ppo["n_steps"])
        after = evaluate_retrieval(model, held_out, 20, seed=1_000_000)
    finally:
        venv.close()
        held_out.close()
    assert before.entropy > 1.75  # uniform over six is 1.79
    assert after.greedy_accuracy >= 0.9, after
    assert after.sampled_fraction > 0.25 and after.entropy < 1.65, after


def test_a_household_run_trains_and_is_evaluated_with_each_rule_and_held_out_objects(tmp_path):
    """The long-term memory variant end to end: train from its zoo config (shortened), then evaluate
    the same model with a fixed retention rule and on objects no training task had."""
    config = tmp_path / "household.yml"
    zoo = (ZOO / "memret_ppo_household.yml").read_text()
    config.write_text(zoo.replace("n_timesteps: 6144", "n_timesteps: 32").replace("n_envs: 2", "n_envs: 1")
                      .replace("n_steps: 64", "n_steps: 16").replace("tasks_per_episode: 8", "tasks_per_episode: 2")
                      + "    max_control_steps: 48\n")
    out = tmp_path / "run"
    result = cli("train", "recall", "--controller", "scripted", "--config", config, "--out", out, "--eval-episodes", 2,
                 "--eval-every", 1, "--no-progress")
    assert result.exit_code == 0, result.output
    model = PPO.load(out / "final_model.zip")
    assert model.action_space.nvec.tolist() == [6]  # 3 long-term slots, then 3 per-episode slots
    for args, expected in ((["--retention", "fifo"], ("train", "fifo")), (["--objects", "heldout"], ("heldout", "learned"))):
        result = cli("eval", out / "final_model.zip", "--controller", "scripted", "--episodes", 2, "--json", *args)
        assert result.exit_code == 0, result.output
        report = json.loads(result.stdout.strip().splitlines()[-1])
        assert (report["objects"], report["retention"]) == expected and report["episodes"] == 2
        assert 0.0 <= report["needed_fact_gone_rate"] <= 1.0


def test_two_runs_of_the_same_command_and_seed_evaluate_identically(tmp_path):
    """Every comparison of runs rests on this: the same config and seed, with two physics worker processes,
    give the same held-out evaluations, to the last digit (with the default config's episode exploration)."""
    config = tmp_path / "tiny.yml"
    config.write_text(TINY.replace("n_envs: 1", "n_envs: 2") + "  policy_kwargs:\n    exploration: episode\n")
    histories = []
    for name in ("first", "second"):
        result = cli("train", "recall", "--config", config, "--out", tmp_path / name, "--seed", 3,
                     "--eval-episodes", 2, "--eval-every", 1, "--no-progress")
        assert result.exit_code == 0, result.output
        histories.append((tmp_path / name / "evaluations.jsonl").read_text())
    assert histories[0] == histories[1] and len(histories[0].splitlines()) == 2


def test_a_run_stops_at_its_retrieval_target_and_says_so(tmp_path, monkeypatch):
    """--stop-at-greedy ends a run at the first held-out evaluations that reach it, short of the config's budget,
    and the summary keeps the round and the target. (Round 1's evaluation is read as perfect: a tiny run's learner
    does not reach a target in seconds; the callback's own test learns one for real.)"""
    import dataclasses

    from sb3_memret.callbacks import evaluation

    real = evaluation.evaluate_retrieval

    def perfect_from_round_1(model, *args, **kwargs):
        report = real(model, *args, **kwargs)
        return dataclasses.replace(report, greedy_accuracy=1.0) if model._n_updates else report

    monkeypatch.setattr(evaluation, "evaluate_retrieval", perfect_from_round_1)
    config = tmp_path / "tiny.yml"
    config.write_text(TINY.replace("n_timesteps: 32", "n_timesteps: 320") + "  eval_episodes: 1\n  eval_every: 1\n")
    result = cli("train", "recall", "--config", config, "--out", tmp_path / "run", "--no-progress",
                 "--stop-at-greedy", "0.99", "--stop-patience", "1")
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["stop_at_greedy"] == 0.99 and summary["stop_patience"] == 1
    assert summary["stopped_at_target_round"] == 1 and summary["rounds"] == 1 and summary["num_timesteps"] < 32
    assert [row["round"] for row in read_history(tmp_path / "run")] == [0, 1]
    assert "stopped at round 1" in result.output and (tmp_path / "run" / "final_model.zip").exists()
    assert cli("train", "recall", "--out", tmp_path / "bad", "--stop-at-greedy", "0").exit_code == 2
