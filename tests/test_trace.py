"""The first-decision retrieval trace on the real DrawerRecall-v0 env with untrained models."""

import json

import gymnasium as gym
import pytest
import torch
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_memret.envs import RECALL_ENV_ID
from sb3_memret.policy.policy import MemoryRetrievalPolicy
from sb3_memret.policy.ppo import MemRetPPO
from sb3_memret.analysis.trace import RetrievalTrace, TraceRow, trace_first_retrieval, trace_models


@pytest.fixture(scope="module")
def env(encoder):
    env = gym.make(RECALL_ENV_ID, controller="scripted", encoder=encoder)
    yield env
    env.close()


@pytest.fixture(scope="module")
def episode(env):
    """The first seed whose seeded bank still holds the true cube memory: (seed, reset info)."""
    for seed in range(20):
        _, info = env.reset(seed=seed)
        if info["true_slot"] >= 0:
            return seed, info
    pytest.fail("no seed in 0..19 keeps the true memory in the bank")


def make_model(env, seed=0):
    return MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([lambda: env]), seed=seed, n_steps=8, batch_size=8)


@pytest.fixture(scope="module")
def model(env):
    return make_model(env)


def with_scores(model, monkeypatch, true_slot, true_score):
    """Make the retriever score the true slot ``true_score`` and every other slot 0."""
    def scores(features):
        out = torch.zeros_like(features["mask"])
        out[:, true_slot] = true_score
        return out

    monkeypatch.setattr(model.policy, "scores", scores)
    return model


def assert_consistent(trace, info):
    n_valid = len(info["memory_texts"])
    assert len(trace.rows) == n_valid == 6
    assert sorted(row.slot for row in trace.rows) == list(range(n_valid))
    for row in trace.rows:
        assert row.text == info["memory_texts"][row.slot]
    (true_row,) = [row for row in trace.rows if row.true]
    assert true_row.slot == info["true_slot"]
    assert true_row.text == f"the cube is in drawer layer {trace.group}."
    assert trace.group == info["group"] == str(info["target_layer"])
    assert sum(row.sampled for row in trace.rows) == 1  # K = 1
    scores = [row.score for row in trace.rows]
    assert scores == sorted(scores, reverse=True)
    probs = [row.probability for row in trace.rows]
    assert all(0.0 <= p <= 1.0 for p in probs)
    assert sum(probs) == pytest.approx(1.0)
    assert trace.greedy_correct == trace.rows[0].true
    assert trace.temperature == 0.5


def test_untrained_trace_describes_the_bank(model, env, episode):
    seed, info = episode
    trace = trace_first_retrieval(model, env, seed, "untrained")
    assert (trace.label, trace.seed, trace.instruction) == ("untrained", seed, "pick out the cube.")
    assert_consistent(trace, info)
    assert all(0.0 < row.probability < 1.0 for row in trace.rows)


def test_same_seeds_give_the_same_trace(model, env, episode):
    seed, _ = episode
    assert trace_first_retrieval(model, env, seed, "a", sample_seed=3) == trace_first_retrieval(model, env, seed, "a", sample_seed=3)
    # the untrained retriever is near uniform, so the sample seed (and only it) moves the sampled pick
    picks = {next(r.slot for r in trace_first_retrieval(model, env, seed, "a", s).rows if r.sampled) for s in range(10)}
    assert len(picks) > 1


def test_trace_leaves_the_global_torch_rng_alone(model, env, episode):
    torch.manual_seed(123)
    state = torch.get_rng_state()
    trace_first_retrieval(model, env, episode[0], "untrained", sample_seed=5)
    assert torch.equal(torch.get_rng_state(), state)


def test_format_marks_sampled_and_true_rows(model, env, episode):
    trace = trace_first_retrieval(model, env, episode[0], "untrained")
    header, columns, *lines = trace.format().splitlines()
    assert header.startswith("untrained") and ("[CORRECT]" in header) == trace.greedy_correct
    assert ("[WRONG]" in header) != trace.greedy_correct
    assert "score" in columns and "p(first)" in columns
    assert len(lines) == len(trace.rows)
    for line, row in zip(lines, trace.rows):
        assert line[0] == ("*" if row.sampled else " ")
        assert line[1] == ("C" if row.true else " ")
        assert row.text in line


def test_to_dict_is_json(model, env, episode):
    trace = trace_first_retrieval(model, env, episode[0], "untrained")
    data = json.loads(json.dumps(trace.to_dict()))
    assert data["greedy_correct"] == trace.greedy_correct
    assert [row["text"] for row in data["rows"]] == [row.text for row in trace.rows]
    assert data["group"] == trace.group


def test_a_retriever_that_prefers_the_true_memory_is_correct(env, episode, monkeypatch):
    seed, info = episode
    model = with_scores(make_model(env), monkeypatch, info["true_slot"], 10.0)  # a gap of 20 logits at tau 0.5
    for sample_seed in range(5):
        trace = trace_first_retrieval(model, env, seed, "trained", sample_seed)
        assert_consistent(trace, info)
        assert trace.greedy_correct and trace.rows[0].true
        assert trace.rows[0].sampled and trace.rows[0].probability > 0.999
    lines = trace.format().splitlines()
    assert "[CORRECT]" in lines[0]
    assert lines[2].startswith("*C")


def test_a_retriever_that_avoids_the_true_memory_is_wrong(env, episode, monkeypatch):
    seed, info = episode
    model = with_scores(make_model(env), monkeypatch, info["true_slot"], -10.0)
    trace = trace_first_retrieval(model, env, seed, "misled")
    assert_consistent(trace, info)
    assert not trace.greedy_correct and trace.rows[-1].true
    assert not trace.rows[-1].sampled
    assert "[WRONG]" in trace.format().splitlines()[0]


def test_trace_models_traces_each_model_on_the_same_bank(env, encoder, episode, monkeypatch):
    seed, info = episode
    first, second = make_model(env, seed=0), with_scores(make_model(env, seed=1), monkeypatch, info["true_slot"], 10.0)
    traces = trace_models([("first", first), ("second", second)], {"controller": "scripted", "encoder": encoder}, seed)
    assert [t.label for t in traces] == ["first", "second"]
    banks = [{row.slot: row.text for row in t.rows} for t in traces]
    assert banks[0] == banks[1] == dict(enumerate(info["memory_texts"]))
    for trace in traces:
        assert_consistent(trace, info)
    assert [row.score for row in traces[0].rows] != [row.score for row in traces[1].rows]
    assert traces[1].greedy_correct



def test_a_bank_without_the_true_memory_says_so():
    rows = (TraceRow(0, "the key is in drawer layer 1.", 0.2, 0.6, True, False),
            TraceRow(1, "the robot is holding the mug.", -0.1, 0.4, False, False))
    trace = RetrievalTrace("after eviction", "pick out the cube.", 0, "2", 0.5, rows)
    assert not trace.greedy_correct
    assert "the true memory is not in the bank" in trace.format()
