"""Callbacks and the run logger on the synthetic bank task: what gets logged, saved and kept."""

import csv
import json

import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_memret.callbacks import (PhaseTimingCallback, RetrievalEvalCallback, RolloutRetrievalCallback,
                                  RoundCheckpointCallback, StopOnRetrievalTarget, checkpoint_path, latest_checkpoint)
from sb3_memret.policy.policy import MemoryRetrievalPolicy
from sb3_memret.policy.ppo import MemRetPPO
from sb3_memret.common.run_logger import make_run_logger
from toy_bank import ToyBankEnv

ROUND = 32


def train_toy(tmp_path, rounds=3, keep=2):
    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=ROUND, batch_size=ROUND, seed=0)
    model.set_logger(make_run_logger(tmp_path, ("csv", "tensorboard")))
    evaluator = RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), n_eval_episodes=8, best_model_save_path=tmp_path,
                                      history_path=tmp_path / "evaluations.jsonl")
    checkpointer = RoundCheckpointCallback(tmp_path / "checkpoints", keep=keep)
    model.learn(ROUND * rounds, callback=[RolloutRetrievalCallback(), evaluator, checkpointer])
    model.logger.close()
    return model, evaluator


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_every_round_logs_rollout_and_eval_metrics(tmp_path):
    train_toy(tmp_path, rounds=3)
    rows = read_csv(tmp_path / "progress.csv")
    assert len(rows) == 4  # rounds 0-2 at collection time, then the final policy
    for key in ("eval/greedy_accuracy", "eval/sampled_fraction", "eval/entropy", "eval/success", "eval/mean_return",
                "eval/mean_reward", "eval/true_evicted_rate", "eval/round"):
        assert all(row[key] != "" for row in rows), key
    for key in ("rollout/sampled_fraction", "rollout/success", "rollout/episodes", "rollout/true_evicted_rate"):
        assert all(row[key] != "" for row in rows[:3]), key
    assert [int(float(row["eval/round"])) for row in rows] == [0, 1, 2, 3]
    assert any(p.name.startswith("events.out.tfevents") for p in (tmp_path / "tensorboard").iterdir())


def test_rollout_metrics_say_what_each_round_teaches_the_retriever(tmp_path):
    """Retrieving the true memory earns the toy's only reward, so its advantage gap is positive, and the
    true memory's logit margin over the best decoy grows round by round as the retriever learns it."""
    train_toy(tmp_path, rounds=6)
    rows = [row for row in read_csv(tmp_path / "progress.csv") if row.get("rollout/advantage_gap")]
    assert len(rows) == 6
    assert all(float(row["rollout/advantage_gap"]) > 1 and float(row["rollout/advantage_gap_t"]) > 10 for row in rows)
    margins = [float(row["rollout/score_margin"]) for row in rows]
    assert margins == sorted(margins) and margins[0] < 0.05 < 0.3 < margins[-1]
    assert float(rows[0]["rollout/greedy_accuracy"]) < 0.5 and float(rows[-1]["rollout/greedy_accuracy"]) == 1.0


def test_history_best_model_and_pruned_checkpoints(tmp_path):
    model, evaluator = train_toy(tmp_path, rounds=3, keep=2)
    history = [json.loads(line) for line in (tmp_path / "evaluations.jsonl").read_text().splitlines()]
    assert [row["round"] for row in history] == [0, 1, 2, 3]
    assert (tmp_path / "best_model.zip").exists()
    assert evaluator.best_key == max((r["greedy_accuracy"], r["success"]["overall"], r["sampled_fraction"])
                                     for r in history)
    kept = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert kept == ["memret_64_steps.zip", "memret_96_steps.zip"]
    assert latest_checkpoint(tmp_path / "checkpoints") == checkpoint_path(tmp_path / "checkpoints", 96)
    # a checkpoint holds the policy after the update, ready to continue
    loaded = MemRetPPO.load(latest_checkpoint(tmp_path / "checkpoints"))
    assert loaded.num_timesteps == 96 and loaded._n_updates == model._n_updates


def test_latest_checkpoint_of_empty_folder(tmp_path):
    assert latest_checkpoint(tmp_path) is None
    (tmp_path / "memret_x_steps.zip").write_text("")
    assert latest_checkpoint(tmp_path) is None


def test_csv_appends_and_backfills_new_columns(tmp_path):
    logger = make_run_logger(tmp_path, ("csv",))
    logger.record("a", 1)
    logger.dump(0)
    logger.close()
    logger = make_run_logger(tmp_path, ("csv",))  # a resumed run
    logger.record("a", 2)
    logger.record("b", 3)
    logger.dump(1)
    logger.close()
    rows = read_csv(tmp_path / "progress.csv")
    assert rows == [{"a": "1", "b": ""}, {"a": "2", "b": "3"}]


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="unknown log format 'xml'"):
        make_run_logger("/tmp", ("xml",))
    with pytest.raises(ValueError, match="every and keep"):
        RoundCheckpointCallback("/tmp", every=0)
    with pytest.raises(ValueError, match="n_eval_episodes"):
        RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), n_eval_episodes=0)


def test_the_progress_bar_follows_evaluations_and_counts_them_in_the_time_left(tmp_path):
    import io

    from sb3_memret.callbacks import RunProgressCallback

    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=ROUND, batch_size=ROUND, seed=0)
    evaluator = RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), n_eval_episodes=8, eval_every=2)
    stream = io.StringIO()
    progress = RunProgressCallback(evaluator, file=stream, mininterval=0)
    seen = []
    listener = type("Listener", (), {"evaluation_started": lambda self, r, n: seen.append(("start", r, n)),
                                     "evaluation_episode": lambda self: seen.append("episode"),
                                     "evaluation_finished": lambda self, report: seen.append("end")})()
    evaluator.listeners.append(listener)
    model.learn(ROUND * 5, callback=[evaluator, progress])
    # rounds 0, 2, 4 and the final one are evaluated, each told as it starts, episode by episode, and as it ends
    assert [event for event in seen if event not in ("episode", "end")] == [("start", r, 8) for r in (0, 2, 4, 5)]
    assert seen.count("episode") == 4 * 8 and seen.count("end") == 4
    text = stream.getvalue()
    assert "evaluating round 2" in text and "8/8 episodes" in text and "decisions/s" in text and "left" in text
    assert progress.eval_episodes_done == 32 and progress.trained == ROUND * 5
    assert progress.bar.n == ROUND * 5
    # after round 2's evaluation, the rounds 4 and 5 evaluations are still to come
    model.num_timesteps, model._n_updates = ROUND * 2 + 1, 2 * model.n_epochs
    assert evaluator.episodes_left(ROUND * 5) == 2 * 8


def test_round_zero_and_the_final_evaluation_may_play_their_own_episode_counts(tmp_path):
    """n_initial_episodes sets round 0's evaluation (the untrained learner's) apart and n_final_episodes the one at
    training's end; the others play n_eval_episodes, and the history says how many each played."""
    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=ROUND, batch_size=ROUND, seed=0)
    evaluator = RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), n_eval_episodes=8, eval_every=2,
                                      n_initial_episodes=3, n_final_episodes=12,
                                      history_path=tmp_path / "evaluations.jsonl")
    started = []
    evaluator.listeners.append(type("Listener", (), {"evaluation_started": lambda self, r, n: started.append((r, n)),
                                                     "evaluation_episode": lambda self: None,
                                                     "evaluation_finished": lambda self, report: None})())
    model.learn(ROUND * 3, callback=evaluator)
    assert started == [(0, 3), (2, 8), (3, 12)]
    rows = [json.loads(line) for line in (tmp_path / "evaluations.jsonl").read_text().splitlines()]
    assert [(row["round"], row["episodes"]) for row in rows] == [(0, 3), (2, 8), (3, 12)]
    for bad in ({"n_initial_episodes": 0}, {"n_final_episodes": 0}):
        with pytest.raises(ValueError, match="n_initial_episodes, n_final_episodes"):
            RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), **bad)


def test_the_phase_timer_splits_learning_into_collection_updates_and_evaluations():
    """PhaseTimingCallback: each phase measured, every evaluation counted once whichever side of the evaluator the
    timer stands, and the parts no more than the whole."""
    import time

    for timer_first in (True, False):
        model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=ROUND, batch_size=ROUND, seed=0)
        evaluator = RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), n_eval_episodes=4, eval_every=2)
        timer = PhaseTimingCallback(evaluator)
        start = time.perf_counter()
        model.learn(ROUND * 3, callback=[timer, evaluator] if timer_first else [evaluator, timer])
        whole = time.perf_counter() - start
        split = timer.split()
        assert list(split["evaluate_by_round"]) == ["0", "2", "3"]
        assert min(split["collect"], split["update"], split["evaluate"]) > 0
        assert split["evaluate"] == pytest.approx(sum(split["evaluate_by_round"].values()))
        assert split["collect"] + split["update"] + split["evaluate"] <= whole


def test_evaluations_leave_training_as_it_was():
    """Held-out evaluations draw from a generator of their own: how often a run evaluates does not change
    what it learns (with episode exploration, whose noise comes from torch's global generator)."""
    import torch

    params = []
    for eval_every in (1, 100):
        model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=ROUND, batch_size=ROUND, seed=0,
                          policy_kwargs={"exploration": "episode"})
        evaluator = RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), n_eval_episodes=8, eval_every=eval_every)
        model.learn(ROUND * 3, callback=evaluator)
        params.append(model.policy.state_dict())
    assert all(torch.equal(value, params[1][key]) for key, value in params[0].items())


@pytest.mark.parametrize("groups, on_stdout", [(("1", "2"), True),
                                                (("BlinkCountButtonPressEasy-VLA-v0",
                                                  "BlinkCountButtonPressMedium-VLA-v0"), False)])
def test_per_group_success_leaves_the_stdout_table_only_when_sb3_would_cut_two_keys_alike(tmp_path, monkeypatch,
                                                                                          capsys, groups, on_stdout):
    """SB3's stdout table cuts keys to 36 characters and refuses a dump with two alike, which a run across the
    short split's 32 tasks met at its first round; per-task success then goes to the CSV alone."""
    from sb3_memret.callbacks import evaluation as evaluation_module
    from sb3_memret.evaluation.retrieval import RetrievalReport

    report = RetrievalReport(episodes=2, decisions=4, greedy_accuracy=1.0, sampled_fraction=1.0, entropy=0.1,
                             success={"overall": 0.5, groups[0]: 1.0, groups[1]: 0.0},
                             episodes_per_group={groups[0]: 1, groups[1]: 1})
    monkeypatch.setattr(evaluation_module, "evaluate_retrieval", lambda *args, **kwargs: report)
    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=ROUND, batch_size=ROUND, seed=0)
    model.set_logger(make_run_logger(tmp_path, ("stdout", "csv")))
    model.learn(ROUND, callback=[RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), n_eval_episodes=2)])
    model.logger.close()
    row = read_csv(tmp_path / "progress.csv")[0]
    assert float(row[f"eval/success_group_{groups[0]}"]) == 1.0 and float(row[f"eval/success_group_{groups[1]}"]) == 0
    printed = capsys.readouterr().out
    assert "| eval/" in printed and "success " in printed  # the overall figure always shows
    assert ("success_group_" in printed) == on_stdout


def test_training_stops_once_held_out_retrieval_reaches_the_target_and_a_resume_stops_again(tmp_path):
    """The toy's retriever learns its true memory within a few rounds: with a target, training ends there, not at
    its budget; the streak is counted from the run's history, so a resumed run stops at once."""
    def learn(model, rounds):
        evaluator = RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), n_eval_episodes=8,
                                          history_path=tmp_path / "evaluations.jsonl")
        stopper = StopOnRetrievalTarget(evaluator, greedy_accuracy=1.0, patience=2)
        model.learn(ROUND * rounds, callback=[evaluator, stopper], reset_num_timesteps=False)
        return evaluator, stopper

    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=ROUND, batch_size=ROUND, seed=0)
    model.set_logger(make_run_logger(tmp_path, ("csv",)))
    _, stopper = learn(model, rounds=40)
    history = [json.loads(line) for line in (tmp_path / "evaluations.jsonl").read_text().splitlines()]
    assert stopper.reached is not None and stopper.reached < 40 and stopper.stopped == stopper.reached
    assert [row["greedy_accuracy"] for row in history[-2:]] == [1.0, 1.0]
    assert history[0]["greedy_accuracy"] < 1.0  # it had to learn
    assert not any(a["greedy_accuracy"] == b["greedy_accuracy"] == 1.0 for a, b in zip(history[:-2], history[1:-1]))
    rounds = model._n_updates // model.n_epochs
    assert rounds == stopper.reached == history[-1]["round"]  # no update after the evaluation that met it

    _, again = learn(model, rounds=40)
    assert again.reached == stopper.reached and model._n_updates // model.n_epochs == rounds


def test_a_round_evaluated_twice_counts_once_towards_the_target(tmp_path):
    """A run resumed within a round evaluates the same policy again: the same evidence, not a second round."""
    history = tmp_path / "evaluations.jsonl"
    history.write_text("".join(json.dumps({"round": r, "greedy_accuracy": g}) + "\n"
                               for r, g in ((0, 0.2), (5, 1.0), (5, 1.0))))
    evaluator = RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), n_eval_episodes=1, history_path=history)
    stopper = StopOnRetrievalTarget(evaluator, greedy_accuracy=1.0, patience=2)
    stopper.init_callback(MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=ROUND, batch_size=ROUND))
    assert stopper.streak == 1 and stopper.reached is None
    stopper._count(1.0, 10)
    assert stopper.reached == 10


def test_a_retrieval_target_out_of_range_is_named():
    evaluator = RetrievalEvalCallback(DummyVecEnv([ToyBankEnv]), n_eval_episodes=1)
    with pytest.raises(ValueError, match="greedy_accuracy must be in"):
        StopOnRetrievalTarget(evaluator, greedy_accuracy=1.5)
    with pytest.raises(ValueError, match="patience must be >= 1"):
        StopOnRetrievalTarget(evaluator, greedy_accuracy=0.9, patience=0)
