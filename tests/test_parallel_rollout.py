"""run_jobs: controller episodes in one env or over physics workers with one controller, results in job order."""

from collections import Counter

import psutil
import pytest

from sb3_memret.evaluation import parallel as parallel_rollout
from sb3_memret.evaluation.parallel import EpisodeJob, run_jobs
from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer.prompts import condition_prompt
from sb3_memret.common.workers import WorkerDiedError

DRAWER = DrawerTask()

# The slow episode (a wrong layer plays to the 400-step limit) comes first, so with two workers
# later jobs finish before it: results must still come back in job order.
JOBS = [
    EpisodeJob(condition_prompt("wrong", 1), 1_000_003, {"target_layer": 1}),
    EpisodeJob(condition_prompt("oracle", 2), 1_000_000, {"target_layer": 2}),
    EpisodeJob(condition_prompt("oracle", 3), 1_000_001, {"target_layer": 3}, replan_every=12),
    EpisodeJob(condition_prompt("none", 1), 1_000_002, {"target_layer": 1}),
]


def play(n_envs):
    received = []
    results = run_jobs("scripted", JOBS, DRAWER, n_envs=n_envs, on_result=lambda job, result: received.append((job, result)))
    return results, received


@pytest.fixture(scope="module")
def in_process():
    return play(n_envs=1)


@pytest.fixture(scope="module")
def two_workers():
    return play(n_envs=2)


@pytest.mark.parametrize("run", ["in_process", "two_workers"])
def test_results_come_back_in_job_order(run, request):
    results, _ = request.getfixturevalue(run)
    assert len(results) == len(JOBS)
    for job, result in zip(JOBS, results):
        assert (result.group, result.seed) == (str(job.reset_options["target_layer"]), job.seed)
    assert [r.success for r in results] == [False, True, True, True]  # the wrong layer fails; the rest succeed
    assert all(1 <= r.steps <= 400 for r in results)


def test_workers_play_exactly_what_one_process_plays(in_process, two_workers):
    assert two_workers[0] == in_process[0]


@pytest.mark.parametrize("run", ["in_process", "two_workers"])
def test_on_result_gets_every_job_and_result_once(run, request):
    results, received = request.getfixturevalue(run)
    assert len(received) == len(JOBS)
    assert Counter(received) == Counter(zip(JOBS, results))


@pytest.mark.parametrize("n_envs", [1, 2])
def test_no_jobs_start_nothing(n_envs, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("run_jobs started an env or a worker for no jobs")

    monkeypatch.setattr(parallel_rollout, "make_physics", refuse)
    monkeypatch.setattr(parallel_rollout, "make_controller", refuse)
    assert run_jobs("scripted", [], DRAWER, n_envs=n_envs, on_result=refuse) == []


def test_n_envs_must_be_positive():
    with pytest.raises(ValueError, match="n_envs must be >= 1, got 0"):
        run_jobs("scripted", JOBS, DRAWER, n_envs=0)


@pytest.mark.parametrize("n_envs", [1, 2], ids=["in-process", "worker"])
def test_replan_interval_longer_than_a_chunk_is_refused(n_envs):
    received = []
    job = EpisodeJob(condition_prompt("oracle", 1), 0, {"target_layer": 1}, replan_every=40)
    with pytest.raises(ValueError, match=r"chunk length.*40"):
        run_jobs("scripted", [job], DRAWER, n_envs=n_envs, on_result=lambda *pair: received.append(pair))
    assert received == []


def test_one_controller_call_per_round_serves_every_env(monkeypatch):
    """Two envs, one controller: every act call carries both envs, and there are as many calls as the
    longest env's rounds (not one per env per round)."""
    from sb3_memret.tasks.drawer.expert import ScriptedDrawerController

    controller = ScriptedDrawerController()
    batches = []
    original = controller._act
    monkeypatch.setattr(controller, "_act", lambda obs, prompts, parsed: batches.append(len(prompts))
                        or original(obs, prompts, parsed))
    results = run_jobs(controller, JOBS[1:], DRAWER, n_envs=2)
    assert set(batches) == {2}
    rounds = [-(-r.steps // (job.replan_every or DRAWER.replan_every)) for r, job in zip(results, JOBS[1:])]
    assert max(rounds) <= len(batches) < sum(rounds)


def test_a_prompt_off_the_template_is_refused_before_anything_starts(monkeypatch):
    monkeypatch.setattr(parallel_rollout, "make_physics", lambda *a, **k: pytest.fail("started physics"))
    with pytest.raises(ValueError, match="drawer number 2"):
        run_jobs("scripted", [EpisodeJob("pick out the cube. the cube is in drawer number 2.", 0, {"target_layer": 2})], DRAWER)


def test_a_killed_physics_worker_is_reported():
    """A worker killed mid-run (out of memory, a signal) ends the run with WorkerDiedError naming it."""
    killed = []

    def kill_a_worker(job, result):
        if not killed:
            workers = [p for p in psutil.Process().children() if "spawn_main" in " ".join(p.cmdline())]
            workers[0].kill()
            killed.append(workers[0].pid)

    jobs = [EpisodeJob(condition_prompt("oracle", 1), seed, {"target_layer": 1}) for seed in range(8)]
    with pytest.raises(WorkerDiedError, match=r"physics worker \d \(pid \d+\) killed by SIGKILL"):
        run_jobs("scripted", jobs, DRAWER, n_envs=2, on_result=kill_a_worker)
    assert killed
