"""RecallVecEnv: one controller call per decision round for N envs, per-env seeds and
auto-reset, the retention push, and physics workers that are named when they die."""

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
from sb3_memret.physics.backends import InProcessPhysics, ProcessPhysics
from sb3_memret.physics import make_physics
from sb3_memret.envs.vec_env import make_recall_vec_env, recall_vec_env
from sb3_memret.policy.networks import RetentionScorer
from sb3_memret.common.workers import WorkerDiedError

SHORT = {"max_control_steps": 16}


class CountingController(ScriptedDrawerController):
    """The scripted expert, counting its act calls and the batch size of each."""

    def __init__(self):
        super().__init__()
        self.batches: list[int] = []
        self.resets: list[list[int]] = []

    def reset_envs(self, env_ids, seeds):
        self.resets.append(list(env_ids))
        super().reset_envs(env_ids, seeds)

    def _act(self, obs, prompts, parsed):
        self.batches.append(len(prompts))
        return super()._act(obs, prompts, parsed)


@pytest.mark.parametrize("n_envs", [1, 3])
def test_one_controller_call_per_decision_round_whatever_n(n_envs, encoder):
    controller = CountingController()
    venv = make_recall_vec_env(n_envs, {"controller": controller, "encoder": encoder, "max_control_steps": 24}, seed=0)
    try:
        venv.reset()
        for _ in range(5):  # 24 steps = 3 decisions: every env ends and restarts in between
            venv.step(np.zeros((n_envs, 1), dtype=np.int64))
        assert controller.batches == [n_envs] * 5
        assert venv.unwrapped.controller_calls == 5
        assert controller.resets == [list(range(n_envs))]  # the episodes that ended were restarted together
    finally:
        venv.close()


def test_envs_in_workers_are_seeded_apart_and_receive_retention_weights(encoder):
    venv = make_recall_vec_env(2, {**SHORT, "encoder": encoder}, seed=7)
    try:
        assert isinstance(venv.unwrapped.physics, ProcessPhysics)
        obs = venv.reset()
        assert obs["memories"].shape == (2, 6, 384) and obs["mask"].shape == (2, 6)
        assert not np.array_equal(obs["memories"][0], obs["memories"][1])  # seeds 7 and 8 differ
        weights = RetentionScorer().state_dict()
        venv.env_method("set_retention_weights", weights, age_unit="steps")
        assert venv.unwrapped.retention is not None
        for _ in range(2):
            obs, rewards, dones, infos = venv.step(np.zeros((2, 1), dtype=np.int64))
        assert dones.all() and all("episode" in info for info in infos)  # VecMonitor saw both episodes end
        assert all(set(info["terminal_observation"]) == set(obs) for info in infos)
    finally:
        venv.close()


def test_env_i_of_a_batch_plays_as_the_same_env_alone(encoder):
    """Batching changes nothing an env sees: env 1 of a seed-7 batch of two plays exactly as one env seeded 8."""
    kwargs = {"encoder": encoder, "max_control_steps": 40}
    pair, alone = make_recall_vec_env(2, kwargs, seed=7), make_recall_vec_env(1, kwargs, seed=8)
    try:
        obs_pair, obs_alone = pair.reset(), alone.reset()
        np.testing.assert_array_equal(obs_pair["memories"][1], obs_alone["memories"][0])
        for step in range(6):  # past the end of the first episodes (5 decisions)
            slots = np.array([[step % 6], [(step + 2) % 6]])
            obs_pair, r_pair, d_pair, i_pair = pair.step(slots)
            obs_alone, r_alone, d_alone, i_alone = alone.step(slots[1:])
            assert r_pair[1] == pytest.approx(r_alone[0], abs=1e-7) and d_pair[1] == d_alone[0]
            assert i_pair[1]["prompt"] == i_alone[0]["prompt"]
            assert i_pair[1]["memory_texts"] == i_alone[0]["memory_texts"]
            np.testing.assert_array_equal(obs_pair["memories"][1], obs_alone["memories"][0])
    finally:
        pair.close()
        alone.close()


def test_a_mode_switched_between_evaluations_plays_as_a_fresh_env_in_that_mode(encoder):
    """set_mode lets one set of workers serve several conditions: after a recall episode, the same seed
    played in oracle, then none, gives the prompts and rewards of an env built in that mode."""
    kwargs = {"encoder": encoder, "max_control_steps": 40}
    switched = make_recall_vec_env(1, {**kwargs, "mode": "recall"}, seed=3)
    try:
        switched.reset()
        switched.step(np.array([[0]]))
        for mode in ("oracle", "none"):
            switched.env_method("set_mode", mode)
            fresh = make_recall_vec_env(1, {**kwargs, "mode": mode}, seed=3)
            try:
                switched.seed(3)
                switched.reset(), fresh.reset()
                for _ in range(3):
                    (_, r_switched, _, i_switched), (_, r_fresh, _, i_fresh) = (
                        switched.step(np.array([[0]])), fresh.step(np.array([[0]])))
                    assert i_switched[0]["prompt"] == i_fresh[0]["prompt"]
                    assert r_switched[0] == pytest.approx(r_fresh[0])
            finally:
                fresh.close()
            assert ("drawer layer" in i_switched[0]["prompt"]) == (mode == "oracle")
        with pytest.raises(ValueError, match="unknown mode 'forgetful'"):
            switched.env_method("set_mode", "forgetful")
    finally:
        switched.close()


def test_one_env_stays_in_process_and_bad_arguments_are_refused(encoder):
    venv = make_recall_vec_env(1, {**SHORT, "encoder": encoder})
    try:
        assert isinstance(venv.unwrapped.physics, InProcessPhysics)
        venv.reset()
        with pytest.raises(ValueError, match=r"actions must be 1 slot indices in \[0, 6\) per env, got \[\[6\]\]"):
            venv.step(np.array([[6]]))
    finally:
        venv.close()
    with pytest.raises(ValueError, match="n_envs must be >= 1, got 0"):
        make_recall_vec_env(0)
    with pytest.raises(ValueError, match=r"unknown physics backend 'threads'; expected one of \['auto', 'inprocess'"):
        make_physics("threads", 2, {}, 16, task="drawer")
    with pytest.raises(ValueError, match="a Ray address .* needs the ray backend, not 'process'"):
        make_physics("process", 2, {}, 16, ray_address="ray://head:10001", task="drawer")


def test_stepping_before_reset_is_refused(encoder):
    venv = recall_vec_env(1, encoder=encoder, **SHORT)
    try:
        with pytest.raises(RuntimeError, match="reset the envs before stepping them"):
            venv.step(np.zeros((1, 1), dtype=np.int64))
    finally:
        venv.close()


def test_a_killed_physics_worker_is_named_and_the_rest_shut_down(encoder):
    """SIGKILL one worker (what the out-of-memory killer does): the next step names it, its pid and
    the signal, and close() still ends the live worker."""
    venv = make_recall_vec_env(2, {**SHORT, "encoder": encoder})
    workers = venv.unwrapped.physics.processes
    try:
        venv.reset()
        os.kill(workers[1].pid, signal.SIGKILL)
        workers[1].join(timeout=10)
        with pytest.raises(WorkerDiedError, match=rf"^physics worker 1 \(pid {workers[1].pid}\) killed by SIGKILL"):
            venv.step(np.zeros((2, 1), dtype=np.int64))
    finally:
        venv.close()
    assert not any(p.is_alive() for p in workers)


def test_physics_workers_leave_stop_signals_to_the_trainer(encoder):
    """Ctrl-C and a scheduler's SIGTERM reach every process of the group; workers ignore both, so the
    trainer can checkpoint and then close them."""
    venv = make_recall_vec_env(2, {**SHORT, "encoder": encoder})
    workers = venv.unwrapped.physics.processes
    try:
        venv.reset()
        for worker in workers:
            os.kill(worker.pid, signal.SIGTERM)
            os.kill(worker.pid, signal.SIGINT)
        obs, *_ = venv.step(np.zeros((2, 1), dtype=np.int64))
        assert obs["mask"].shape == (2, 6) and all(p.is_alive() for p in workers)
    finally:
        venv.close()
    assert not any(p.is_alive() for p in workers)


HOUSEHOLD = dict(objects="train", n_objects=3, memory_source="observed", capacity=3, long_term_capacity=3,
                 location_decoys=0, holding_decoys=2, hearsay_per_episode=1, move_probability=0.0, tasks_per_episode=2)


def test_a_household_remembers_across_tasks_and_a_learning_episode_spans_several(encoder):
    venv = recall_vec_env(1, mode="oracle", controller=ScriptedDrawerController(), encoder=encoder,
                              max_control_steps=400, retention="fifo", observe_potential=True, **HOUSEHOLD)
    assert venv.observation_space["memories"].shape == (6, 384) and venv.action_space.nvec.tolist() == [6]
    venv.seed(3)
    obs = venv.reset()
    assert obs["potential"][0, 0] == pytest.approx((1 - venv.gamma) * venv.frames[0].potential)
    memory, placement = venv.memories[0], dict(venv.households[0].placement)
    first_target, first_layer = memory.target, memory.truth.details["target_layer"]
    assert [e.text for e in memory.long_term.entries] == [memory.long_term.entries[0].text]  # one hearsay fact
    assert not {e.entity for e in memory.long_term.entries} & set(placement)  # nothing about the household yet
    tasks, dones = [], []
    while len(tasks) < 2:
        obs, _, done, infos = venv.step(np.zeros((1, 1), dtype=np.int64))
        dones.append(bool(done[0]))
        assert obs["potential"][0, 0] == pytest.approx((1 - venv.gamma) * venv.frames[0].potential)
        if infos[0].get("task_done"):
            tasks.append({**infos[0], "done": bool(done[0]), "next_potential": obs["potential"][0, 0]})
            if len(tasks) == 1:  # the oracle's drawer was opened: the target was seen there, and is remembered
                assert venv.households[0].placement == placement
                seen = f"the {first_target} is in drawer layer {first_layer}."
                assert seen in [e.text for e in memory.long_term.entries]
                assert memory.target in placement and memory.clock > 0
    assert tasks[0]["success"] and [t["done"] for t in tasks] == [False, True] and dones.count(True) == 1
    assert "terminal_observation" in tasks[1] and tasks[1]["TimeLimit.truncated"]
    # the task's potential was paid by its last reward: the household goes on from the next task's start
    assert tasks[1]["terminal_observation"]["potential"][0] == tasks[1]["next_potential"]
    assert tasks[1]["target_fact_kept"] != tasks[1]["stale_fact_kept"] or not tasks[1]["target_fact_kept"]
    assert all(e.timestamp <= memory.now for e in memory.long_term.entries)
    venv.close()


def test_household_refusals(encoder):
    with pytest.raises(ValueError, match="long-term store is written from what the robot sees"):
        recall_vec_env(1, encoder=encoder, **{**HOUSEHOLD, "memory_source": "seeded"})
    venv = recall_vec_env(1, encoder=encoder, **HOUSEHOLD)
    with pytest.raises(ValueError, match="a household decides where its objects are"):
        venv.reset_envs([0], options=[{"target_layer": 2}])
    venv.close()
    with pytest.raises(ValueError, match="unknown retention rule 'newest'"):
        recall_vec_env(1, encoder=encoder, retention="newest")
    with pytest.raises(ValueError, match="unknown age unit 'days'"):
        recall_vec_env(1, encoder=encoder, age_unit="days")
    venv = recall_vec_env(1, encoder=encoder, **HOUSEHOLD, age_unit="tasks")
    with pytest.raises(ValueError, match="reads ages in 'steps', but this env counts them in 'tasks'"):
        venv.set_retention_weights(RetentionScorer().state_dict(), "steps")
    venv.close()


def test_a_script_that_never_closes_its_envs_still_exits(tmp_path):
    """Workers ignore SIGTERM, which is how multiprocessing ends daemon processes at exit: an env left
    open must close its workers itself, or the interpreter would wait on them forever."""
    script = tmp_path / "left_open.py"
    script.write_text('from sb3_memret.envs.vec_env import make_recall_vec_env\n'
                      'if __name__ == "__main__":\n'
                      '    make_recall_vec_env(2, {"controller": "scripted"}).reset()\n'
                      '    print("left open")\n')
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "left open" in done.stdout, done.stderr
