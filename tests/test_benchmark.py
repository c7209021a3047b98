"""MIKASA-Robo-VLA's protocol by one command: the manifest, the run folder (results, resume, report) and real
episodes in MIKASA's own harness with the agent as its policy."""

from __future__ import annotations

import hashlib
import json
import os
import sys
from collections import Counter
from collections.abc import Mapping
from pathlib import Path

import pytest
from click.testing import CliRunner

from mikasa_support import MIKASA_MISSING

pytest.importorskip("mikasa_robo_suite", reason=MIKASA_MISSING)

from mikasa_robo_suite.vla.benchmarking import BenchmarkTask  # noqa: E402

from sb3_memret.benchmark.manifest import episode_seeds, select_tasks  # noqa: E402
from sb3_memret.benchmark.report import render_report  # noqa: E402
from sb3_memret.benchmark.runner import Plan, Protocol, RunFolder, done_units, results, run_benchmark  # noqa: E402
from sb3_memret.cli import main  # noqa: E402
from sb3_memret.physics.sensor_gate import SensorGate  # noqa: E402

# MIKASA-Robo-VLA's benchmarking page: the short split's memory types
SHORT_SPLIT_TYPES = {"Spatial": 14, "Object": 9, "Negative": 9, "Temporal": 3, "Tracking": 2, "Prospective": 1}


def test_the_manifest_gives_mikasas_splits():
    short = select_tasks("short")
    assert Counter(t.memory_type for t in short) == SHORT_SPLIT_TYPES
    assert all(t.max_episode_steps <= 200 and t.split == "short" for t in short)
    assert {"RememberColor3-VLA-v0", "FindImposterShape9-VLA-v0", "TakeItBack-VLA-v0"} <= {t.env_id for t in short}
    assert (len(select_tasks("medium")), len(select_tasks("long")), len(select_tasks("all"))) == (30, 22, 90)
    assert [t.env_id for t in select_tasks(env_ids=["TakeItBack-VLA-v0", "RememberColor3-VLA-v0"])] == \
        ["TakeItBack-VLA-v0", "RememberColor3-VLA-v0"]


def test_task_selection_refuses_what_is_not_a_benchmark_task():
    with pytest.raises(ValueError, match="NotATask-VLA-v0"):
        select_tasks(env_ids=["NotATask-VLA-v0"])
    with pytest.raises(ValueError, match="huge"):
        select_tasks("huge")
    with pytest.raises(ValueError, match="not both"):
        select_tasks("short", ["TakeItBack-VLA-v0"])


def test_seed_sets_are_disjoint():
    protocol, dev = episode_seeds("protocol", 50), episode_seeds("dev", 50)
    assert protocol[0] == 4242424242 and protocol[-1] == 4242424291 and dev[0] == 5000
    assert not set(protocol) & set(dev)
    with pytest.raises(ValueError, match="test"):
        episode_seeds("test", 5)


def _row(env_id: str, memory_type: str = "Object") -> BenchmarkTask:
    return BenchmarkTask(env_id, "short", memory_type, 25, "", "PPO")


def _plan(episodes: int = 2) -> Plan:
    run = Plan(Protocol(seed_set="dev", episodes=episodes), [_row("A-VLA-v0"), _row("B-VLA-v0", "Spatial"),
                                                             _row("C-VLA-v0", "Negative")], ["none", "oracle"])
    run.refused["C-VLA-v0"] = "needs an asset"
    for env_id in ("A-VLA-v0", "B-VLA-v0"):
        run.controllers[env_id] = {"name": "scripted", "sha256": f"c-{env_id}", "reads": "proprioception"}
        run.task_digests[env_id], run.replan_every[env_id] = f"t-{env_id}", 4
    return run


def _record(env_id: str, condition: str, seed: int, success: bool, **extra) -> dict:
    return {"env_id": env_id, "condition": condition, "seed": seed, "success": success, "return": float(success),
            "steps": 10, "controller_sha256": f"c-{env_id}", "task_sha256": f"t-{env_id}", **extra}


def test_results_count_current_episodes_and_keep_refusals():
    run = _plan()
    records = [_record("A-VLA-v0", "oracle", 5000, True), _record("A-VLA-v0", "oracle", 5001, False),
               _record("A-VLA-v0", "none", 5000, False),
               _record("A-VLA-v0", "none", 5001, True, controller_sha256="old controller"),  # played by other code
               {**_record("B-VLA-v0", "oracle", 5000, False), "error": "RuntimeError: boom"}]
    content = results(run, records)
    a = content["tasks"]["A-VLA-v0"]["conditions"]
    assert a["oracle"] == {"episodes": 2, "seeds": [5000, 5001], "successes": [True, False], "success": 0.5,
                           "returns": [1.0, 0.0], "episode_lengths": [10, 10], "seconds": [None, None],
                           "complete": True}
    assert a["none"]["episodes"] == 1 and not a["none"]["complete"]  # the stale episode does not count
    assert content["tasks"]["B-VLA-v0"]["conditions"]["oracle"]["error"] == "RuntimeError: boom"
    assert content["tasks"]["C-VLA-v0"]["refused"] == "needs an asset"
    assert content["protocol"]["seeds"] == [5000, 5001]
    done = done_units(run, records)
    assert {(u.env_id, u.condition, u.seed) for u in done} == {("A-VLA-v0", "oracle", 5000),
                                                               ("A-VLA-v0", "oracle", 5001), ("A-VLA-v0", "none", 5000)}
    assert len(run.units(done)) == 2 * 2 * 2 - 3  # C is refused; the errored and the stale units are played again

    report = render_report(content)
    assert "| A-VLA-v0 | Object | 4 | 0% (0/1) * | 50% (1/2) |" in report
    assert "| oracle | 1/3 | 50.0% | 16.7% |" in report  # only A played all of its oracle episodes
    assert "| C-VLA-v0 | needs an asset |" in report and "B-VLA-v0 (oracle) | RuntimeError: boom" in report
    assert "not all of the protocol's episodes played yet" in report  # the footnote of A's partial cell
    assert "## Cost" not in report  # episodes logged before they were timed


def test_the_report_says_what_each_task_cost_to_play():
    run = _plan(episodes=4)
    records = [_record("A-VLA-v0", "oracle", 5000 + i, True, seconds=2.0) for i in range(2)]  # 10 steps in 2 s
    records += [_record("A-VLA-v0", "none", 5000 + i, False, seconds=1.0) for i in range(4)]
    records += [_record("B-VLA-v0", "oracle", 5000, True)]  # untimed: no row
    content = results(run, records)
    assert content["tasks"]["A-VLA-v0"]["conditions"]["oracle"]["seconds"] == [2.0, 2.0]
    report = render_report(content)
    # medians of 6 episodes: 1 s, 10 steps a second; cells: 4 episodes x 2 s + 4 x 1 s = 12 s = 0.2 worker-minutes
    assert "| A-VLA-v0 | 6 | 1.0 | 10 | 0.2 |" in report and "| B-VLA-v0 | 1 |" not in report


def test_code_digests_name_the_code_that_acts():
    from sb3_memret.benchmark.runner import code_digest, task_digest
    from sb3_memret.tasks import make_task

    colour, shape = make_task("RememberColor3-VLA-v0"), make_task("RememberShape3-VLA-v0")
    assert task_digest(colour) == task_digest(make_task("RememberColor5-VLA-v0"))  # one class, one code
    assert task_digest(colour) != task_digest(shape)
    assert code_digest(type(colour.expert())) == code_digest(type(shape.expert()))  # the same touch expert


def test_a_code_digest_counts_imported_names_not_their_home(tmp_path, monkeypatch):
    import importlib.util

    from sb3_memret.benchmark.runner import code_digest

    def digest(source: str) -> str:
        """The digest of class ``Probe`` in a module of the project's namespace holding ``source``."""
        path = tmp_path / "probe.py"
        path.write_text(source + "class Probe:\n    def act(self):\n        return helper('a')\n")
        spec = importlib.util.spec_from_file_location("sb3_memret.digest_probe", path)
        module = importlib.util.module_from_spec(spec)
        monkeypatch.setitem(sys.modules, spec.name, module)
        spec.loader.exec_module(module)
        return code_digest(module.Probe)

    home = digest("from os.path import basename as helper\n")
    assert digest("from posixpath import basename as helper\n") == home  # the helper moved: nothing to replay
    assert digest("from os.path import dirname as helper\n") != home  # another helper acts
    assert digest("import os.path as helper\n") != home


def test_one_worker_plays_in_this_process_with_one_torch_thread(monkeypatch):
    """As every pool worker does: beside other jobs, idle intra-op threads spin-wait after every small op (one
    SeqOfColors5-Long episode took 2.8 times the CPU with two); the caller's setting comes back after."""
    import torch

    from sb3_memret.benchmark import runner

    class Worker:
        def __init__(self, protocol, learners):
            pass

        def play(self, unit):
            return {"unit": unit, "threads": torch.get_num_threads()}

    monkeypatch.setattr(runner, "_Worker", Worker)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        records = list(runner.play_units(["a", "b"], Protocol(seed_set="dev"), None, workers=1))
        assert [r["threads"] for r in records] == [1, 1] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_a_run_folder_resumes_only_under_its_protocol(tmp_path):
    folder = RunFolder(tmp_path)
    folder.check_protocol(Protocol(episodes=3))
    folder.check_protocol(Protocol(episodes=3))
    with pytest.raises(ValueError, match="episodes: 3"):
        folder.check_protocol(Protocol(episodes=50))
    folder.log(_record("A-VLA-v0", "none", 1, True, traceback="Traceback ..."))
    with (tmp_path / "episodes.jsonl").open("a") as f:
        f.write('{"env_id": "A-VLA')  # a line cut off by an interruption
    assert [r["seed"] for r in folder.episodes()] == [1]
    assert "Traceback" in (tmp_path / "errors.log").read_text()


def test_one_benchmark_at_a_time_plays_a_folder(tmp_path):
    """A second benchmark on a folder being played is refused naming the first (it would play every pending
    episode again beside it); the folder is free again once the first ends."""
    import subprocess

    with RunFolder(tmp_path).playing():
        with pytest.raises(ValueError, match=rf"being played by another benchmark \(process {os.getpid()}\)"):
            with RunFolder(tmp_path).playing():
                pass
        other = subprocess.run([sys.executable, "-c", "from pathlib import Path; from sb3_memret.benchmark.runner "
                                f"import RunFolder\nwith RunFolder(Path({str(tmp_path)!r})).playing(): pass"],
                               capture_output=True, text=True)
        assert other.returncode != 0 and "being played by another benchmark" in other.stderr
    with RunFolder(tmp_path).playing():
        pass


def test_the_command_refuses_bad_options_in_one_line(tmp_path):
    runner = CliRunner()
    result = runner.invoke(main, ["benchmark", "mikasa", "--conditions", "oracle,psychic", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "psychic" in result.output and "Traceback" not in result.output
    result = runner.invoke(main, ["benchmark", "mikasa", "--split", "short", "--tasks", "TakeItBack-VLA-v0",
                                  "--out", str(tmp_path)])
    assert result.exit_code == 2 and "not both" in result.output
    # nothing of what was asked can run: one line naming why, a failing exit, no table
    result = runner.invoke(main, ["benchmark", "mikasa", "--tasks", "TakeItBack-VLA-v0", "--controller", "psychic",
                                  "--out", str(tmp_path / "none")])
    assert result.exit_code == 1 and "nothing to play: " in result.output and "psychic" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "none" / "results.json").exists()
    result = runner.invoke(main, ["benchmark", "mikasa", "--tasks", "TakeItBack-VLA-v0", "--conditions", "recall",
                                  "--learners", str(tmp_path / "no-learners"), "--out", str(tmp_path / "none")])
    assert result.exit_code == 1 and "nothing to play: no trained memory learner: expected" in result.output


class _Guarded(Mapping):
    """The harness's observation, failing the test if anything reads what the protocol forbids."""

    def __init__(self, obs):
        self.obs = obs

    def __getitem__(self, key):
        assert key not in ("oracle_info", "task_cue"), f"the agent read {key!r}"
        return self.obs[key]

    def __iter__(self):
        return iter(k for k in self.obs if k not in ("oracle_info", "task_cue"))

    def __len__(self):
        return len(list(iter(self)))


def test_results_and_report_break_success_down_by_cue(monkeypatch):
    run = _plan(episodes=3)
    cues = {5000: "blue", 5001: "red", 5002: "blue"}
    records = [_record("A-VLA-v0", "oracle", seed, seed != 5002, cue=cue) for seed, cue in cues.items()]
    records += [_record("A-VLA-v0", "none", seed, seed == 5001, cue=cue) for seed, cue in cues.items()]
    records += [_record("B-VLA-v0", "oracle", 5000 + i, True, cue=f"{i} cm/s") for i in range(3)]
    content = results(run, records)
    a = content["tasks"]["A-VLA-v0"]["conditions"]
    assert a["oracle"]["by_cue"] == {"blue": {"episodes": 2, "successes": 1}, "red": {"episodes": 1, "successes": 1}}
    assert a["none"]["by_cue"]["red"] == {"episodes": 1, "successes": 1}
    report = render_report(content)
    assert "## By cue" in report
    assert "| A-VLA-v0 | blue | 0/2 | 1/2 |" in report and "| A-VLA-v0 | red | 1/1 | 1/1 |" in report
    assert "| B-VLA-v0 | 0 cm/s |" in report  # three values: listed

    from sb3_memret.benchmark import report as report_module

    monkeypatch.setattr(report_module, "MAX_CUES_SHOWN", 2)  # B's three values are now too many to list
    continuous = [_record("B-VLA-v0", "oracle", 5000 + i, True, cue=f"{i} cm/s") for i in range(3)]
    assert "## By cue" not in render_report(results(_plan(episodes=3), continuous))
    unlabelled = [_record("A-VLA-v0", "oracle", 5000, True), _record("A-VLA-v0", "oracle", 5001, True, cue="red")]
    assert "by_cue" not in results(_plan(), unlabelled)["tasks"]["A-VLA-v0"]["conditions"]["oracle"]


def test_a_folder_played_before_fresh_scenes_existed_resumes_with_reused_ones(tmp_path):
    """protocol.json without fresh_scenes was written when every env reused its scene: it resumes as such, refuses
    fresh scenes, and the command keeps a folder's own setting unless told otherwise (a new folder: fresh)."""
    from sb3_memret.cli.benchmark import _fresh_scenes

    old = Protocol(episodes=3).to_json()
    del old["fresh_scenes"]
    (tmp_path / "protocol.json").write_text(json.dumps(old))
    folder = RunFolder(tmp_path)
    folder.check_protocol(Protocol(episodes=3, fresh_scenes=False))
    with pytest.raises(ValueError, match="fresh_scenes: False"):
        folder.check_protocol(Protocol(episodes=3))
    assert Protocol.from_json(old).fresh_scenes is False
    assert _fresh_scenes(None, tmp_path) is False and _fresh_scenes("fresh", tmp_path) is True
    assert _fresh_scenes(None, tmp_path / "new") is True and _fresh_scenes("reused", tmp_path / "new") is False
    (tmp_path / "protocol.json").write_text("{not json")
    with pytest.raises(Exception, match="not a protocol file"):
        _fresh_scenes(None, tmp_path)


def test_with_fresh_scenes_an_episode_does_not_depend_on_its_workers_earlier_ones():
    """TakeItBack's seed 5006 played after 5005 in one env returns 38.17284 with the harness's reused scene and
    38.17486 alone: the physics engine's state carries across resets. Built anew at each reset, it is the same
    either way, to the last digit."""
    from sb3_memret.benchmark.runner import Unit, _Worker
    from sb3_memret.common.workers import torch_threads

    protocol = Protocol(episodes=50)
    assert protocol.fresh_scenes

    def returns(seeds):
        worker = _Worker(protocol, None)
        with torch_threads(1):
            played = [worker.play(Unit("TakeItBack-VLA-v0", "oracle", seed)) for seed in seeds]
        assert worker.env.unwrapped.reconfiguration_freq == 1
        worker.env.close()
        return [record["return"] for record in played]

    assert returns([5005, 5006])[1] == returns([5006])[0]


def test_the_agent_plays_mikasas_harness_from_cameras_only(tmp_path, monkeypatch):
    """Real episodes of RememberColor3 in MIKASA's own harness, one per condition at a development seed: the
    written facts are the ones the oracle names, so both succeed; the wrong fact fails; nothing forbidden is read;
    a second run over the same folder plays nothing again."""
    from sb3_memret.benchmark import agent as agent_module
    from sb3_memret.benchmark.runner import plan

    forward = agent_module.MemoryAgent.forward
    monkeypatch.setattr(agent_module.MemoryAgent, "forward", lambda self, obs: forward(self, _Guarded(obs)))
    run = plan(Protocol(seed_set="dev", episodes=1), ["oracle", "wrong", "written"],
               env_ids=["RememberColor3-VLA-v0", "ShellGameTouch-VLA-v0"])
    assert "YCB" in run.refused["ShellGameTouch-VLA-v0"]
    content = run_benchmark(run, tmp_path, workers=1)
    cells = content["tasks"]["RememberColor3-VLA-v0"]["conditions"]
    assert {c: cells[c]["successes"] for c in cells} == {"oracle": [True], "wrong": [False], "written": [True]}
    logged = [json.loads(line) for line in (tmp_path / "episodes.jsonl").read_text().splitlines()]
    oracle, = (r["prompt"] for r in logged if r["condition"] == "oracle")
    written, = (r["prompt"] for r in logged if r["condition"] == "written")
    assert written == oracle and written.endswith("the cue cube was lime.")
    assert {r["cue"] for r in logged} == {"lime"}  # the seed's cue, logged for the per-cue breakdown
    assert cells["oracle"]["by_cue"] == {"lime": {"episodes": 1, "successes": 1}}
    assert json.loads((tmp_path / "results.json").read_text()) == content
    again = run_benchmark(run, tmp_path, workers=1)
    assert again == content and len((tmp_path / "episodes.jsonl").read_text().splitlines()) == 3
    from sb3_memret.benchmark.runner import rebuild

    assert rebuild(tmp_path) == content  # the table again from the folder alone (`benchmark report`)
    assert "played yet" not in render_report(content)  # every cell complete: no footnote for partial ones


LEARNER = """n_timesteps: 16
n_envs: 1
n_steps: 16
batch_size: 8
n_epochs: 1
policy_kwargs:
  exploration: episode
env_kwargs:
  task: RememberColor3-VLA-v0
  mode: recall
  capacity: 6
  k: 1
  replan_every: 4
  location_decoys: 5
"""


def test_recall_retrieves_from_the_writers_bank_in_the_harness(tmp_path):
    """``benchmark learners`` trains a (one-round) learner on the real task; the recall condition then plays the
    harness with it: every prompt's fact is one of the bank's (the written cue fact or a decoy worded alike)."""
    import yaml

    from sb3_memret.analysis.learners import learner_rows, learners_table
    from sb3_memret.benchmark.learners import train_learners
    from sb3_memret.benchmark.runner import plan
    from sb3_memret.training.config import parse_section

    env_id = "RememberColor3-VLA-v0"
    (tmp_path / "learners" / env_id).mkdir(parents=True)
    (tmp_path / "learners" / env_id / "config.yml").write_text("{}\n")  # a run stopped before its first checkpoint
    outcomes = train_learners([env_id, "ShellGameTouch-VLA-v0"], tmp_path / "learners", eval_episodes=1,
                              load_config=lambda name: parse_section(yaml.safe_load(LEARNER), name))
    assert [o.status for o in outcomes] == ["trained", "refused"]
    assert (tmp_path / "learners" / env_id / "final_model.zip").is_file()
    assert [o.status for o in train_learners([env_id], tmp_path / "learners")] == ["kept"]
    # the folder's index lists both tasks asked; its table a row each, the refused one never started
    header, _, trained, refused, _, total = learners_table(learner_rows(tmp_path / "learners"))
    assert trained.startswith(f"| {env_id} | ") and "its budget" in trained
    assert refused.startswith("| ShellGameTouch-VLA-v0 | not started |") and total.startswith("1 of 2 trained")

    run = plan(Protocol(seed_set="dev", episodes=1), ["recall"], env_ids=[env_id], learners=tmp_path / "learners")
    content = run_benchmark(run, tmp_path / "run", workers=1)
    assert content["tasks"][env_id]["conditions"]["recall"]["episodes"] == 1
    record, = (json.loads(line) for line in (tmp_path / "run" / "episodes.jsonl").read_text().splitlines())
    model = tmp_path / "learners" / env_id / "final_model.zip"
    assert record["learner_sha256"] == hashlib.sha256(model.read_bytes()).hexdigest()
    cell = content["tasks"][env_id]["conditions"]["recall"]
    assert cell["learner_sha256"] == record["learner_sha256"] and cell["learner_training"]["rounds"] >= 1
    assert not run.current({**record, "learner_sha256": "another learner"})  # played with another model: again
    instruction = "observe the cube's color, wait, then touch the cube of the same color."
    fact = record["prompt"].removeprefix(instruction + " ")
    assert fact.startswith("the ") and fact.endswith(".") and " was " in fact
    missing = plan(Protocol(seed_set="dev", episodes=1), ["recall"], env_ids=[env_id], learners=tmp_path / "none")
    assert "no trained memory learner" in missing.refused_conditions[env_id, "recall"]
    long = plan(Protocol(seed_set="dev", episodes=1), ["recall"], env_ids=["RememberColor3-Long-VLA-v0"],
                learners=tmp_path / "learners")  # a -Long variant without a learner of its own: its short task's
    assert not long.refused_conditions
    cell = results(long, [])["tasks"]["RememberColor3-Long-VLA-v0"]["conditions"]["recall"]
    assert cell["learner"] == str(tmp_path / "learners" / env_id / "final_model.zip")


def test_the_shipped_learner_serves_recall_on_every_short_task_that_runs_here(tmp_path, monkeypatch):
    """Without --learners, recall plays the learner across the short split shipped in the package: every task of the
    split that runs here has it (its bank settings from the shipped run config), and so do their -Long variants; a
    missing one says how to rebuild."""
    from sb3_memret.benchmark import learners as learners_module
    from sb3_memret.benchmark.agent import MemoryLearner
    from sb3_memret.benchmark.learners import learner_tasks
    from sb3_memret.benchmark.runner import plan, split_tasks

    path = learners_module.shipped_learner()
    runnable, _ = split_tasks("short")
    trained = learner_tasks(path)
    assert len(trained) == 32 and set(trained) <= set(runnable)  # what runs without downloaded assets
    run = plan(Protocol(seed_set="dev", episodes=1), ["recall"], split="short", learners=path)
    assert set(run.learner_digests) == set(trained)
    assert all("was not trained on it" in why for why in run.refused_conditions.values())  # a ShellGame with its mug
    learner = MemoryLearner(path, "scripted", "BlinkCountButtonPressEasy-VLA-v0")
    assert learner.settings["capacity"] == 6 and learner.settings["k"] == 1
    long = MemoryLearner(path, "scripted", "RememberColor3-Long-VLA-v0")  # a -Long variant: its short task's bank
    assert long.settings == MemoryLearner(path, "scripted", "RememberColor3-VLA-v0").settings
    with pytest.raises(ValueError, match="not trained on 'BlinkCountButtonPressHard-Long-VLA-v0'"):
        MemoryLearner(path, "scripted", "BlinkCountButtonPressHard-Long-VLA-v0")  # its short task is medium's
    medium = plan(Protocol(seed_set="dev", episodes=1), ["recall"], split="medium", learners=path)
    assert {env_id for env_id in medium.learner_digests} == {
        env_id for env_id in split_tasks("medium")[0] if env_id.startswith("Remember") and env_id.endswith("-Long-VLA-v0")}

    monkeypatch.setattr(learners_module, "SHIPPED_LEARNER", tmp_path / "gone" / "final_model.zip")
    result = CliRunner().invoke(main, ["benchmark", "mikasa", "--tasks", "TakeItBack-VLA-v0", "--conditions", "recall",
                                       "--out", str(tmp_path / "run")])
    assert result.exit_code == 2 and "make learner-multitask" in result.output and not (tmp_path / "run").exists()


def test_each_task_plays_the_first_of_several_learners_that_serves_it(tmp_path):
    """--learners DIR --learners shipped: a task with its own learner in the folder plays it, a task the folder
    lacks plays the shipped learner across the short split, one that neither serves is refused naming both; the
    sources are recorded in order and read back."""
    from sb3_memret.benchmark.learners import shipped_learner
    from sb3_memret.benchmark.learners import find_learner, stored_learners
    from sb3_memret.benchmark.runner import learners_landed, plan
    from sb3_memret.cli.benchmark import _learner_sources

    own = tmp_path / "learners" / "BunchOfColors3-VLA-v0" / "final_model.zip"
    own.parent.mkdir(parents=True)
    own.write_bytes(b"a learner of its own")
    sources = _learner_sources((tmp_path / "learners", Path("shipped")))
    assert sources == (tmp_path / "learners", shipped_learner()) and _learner_sources(()) == (shipped_learner(),)
    tasks = ["BunchOfColors3-VLA-v0", "RememberColor3-Long-VLA-v0", "BlinkCountButtonPressHard-VLA-v0"]
    run = plan(Protocol(seed_set="dev", episodes=1), ["recall"], env_ids=tasks, learners=sources)
    assert find_learner(run.learners, tasks[0])[0] == own
    assert find_learner(run.learners, tasks[1])[0] == shipped_learner()
    assert set(run.learner_digests) == set(tasks[:2])
    why = run.refused_conditions[tasks[2], "recall"]
    assert str(tmp_path / "learners" / tasks[2] / "final_model.zip") in why and "was not trained on it" in why
    assert learners_landed(run) == []  # the learner across tasks is there, but not for it: nothing landed
    saved = results(run, [])["protocol"]["learners"]
    assert saved == [str(tmp_path / "learners"), "shipped"] and stored_learners(saved) == sources  # on any checkout
    assert stored_learners(str(own)) == (own,) and stored_learners(None) == ()


def test_a_learner_that_lands_while_the_table_plays_is_found(tmp_path):
    from sb3_memret.benchmark.runner import learners_landed, plan

    env_id = "RememberColor3-VLA-v0"
    run = plan(Protocol(seed_set="dev", episodes=1), ["none", "recall"], env_ids=[env_id], learners=tmp_path)
    assert (env_id, "recall") in run.refused_conditions and learners_landed(run) == []
    (tmp_path / env_id).mkdir()
    (tmp_path / env_id / "final_model.zip").write_bytes(b"a learner")  # `benchmark learners` finished it meanwhile
    assert learners_landed(run) == [env_id]
    again = plan(run.protocol, ["none", "recall"], env_ids=[env_id], learners=tmp_path)
    assert not again.refused_conditions and learners_landed(again) == []


def test_a_condition_added_to_a_run_folder_keeps_its_table(tmp_path):
    """A run of one condition (or task) into a folder whose results report others reports them all still, and
    plays only its own units."""
    from sb3_memret.benchmark.runner import RESULTS_FILE, plan, widened

    protocol = Protocol(seed_set="dev", episodes=1)
    first = plan(protocol, ["none", "oracle"], env_ids=["RememberColor3-VLA-v0", "TakeItBack-VLA-v0"])
    (tmp_path / RESULTS_FILE).write_text(json.dumps(results(first, [])))
    added = plan(protocol, ["wrong"], env_ids=["RememberColor3-VLA-v0"])
    shown = widened(added, tmp_path)
    assert shown.conditions == ["none", "oracle", "wrong"]
    assert [row.env_id for row in shown.tasks] == ["RememberColor3-VLA-v0", "TakeItBack-VLA-v0"]
    assert [(u.env_id, u.condition) for u in added.units(set())] == [("RememberColor3-VLA-v0", "wrong")]
    assert widened(first, tmp_path) is first  # nothing to add


def test_a_task_that_cannot_run_here_is_refused_with_its_reason(monkeypatch):
    from sb3_memret import tasks
    from sb3_memret.benchmark.runner import plan

    why = "its scripted expert cannot yet take a battery back out of MIKASA's socket"
    monkeypatch.setitem(tasks._UNAVAILABLE, "BatteriesCheckerHard-6-VLA-v0", lambda: why)
    run = plan(Protocol(seed_set="dev", episodes=1), ["none"],
               env_ids=["BatteriesCheckerHard-6-VLA-v0", "BatteriesCheckerEasy-3-VLA-v0"])
    assert run.refused["BatteriesCheckerHard-6-VLA-v0"].startswith(why)
    assert "BatteriesCheckerEasy-3-VLA-v0" not in run.refused
    assert [unit.env_id for unit in run.units(set())] == ["BatteriesCheckerEasy-3-VLA-v0"]


def test_the_agent_renders_only_what_it_reads_and_every_outcome_stays_the_same():
    """The same RememberColor3 episodes with the harness's every-step rendering and with the sensor gate: equal
    outcomes and prompts. The scripted controller reads no images, so under oracle only the reset renders; the
    written condition's writer reads every step's, the base camera's alone (``Task.writer_cameras``) where no
    controller reads; the camera expert reads its decisions' until its cubes are placed."""
    from sb3_memret.benchmark import harness
    from sb3_memret.benchmark.agent import MemoryAgent
    from sb3_memret.tasks import make_task
    from sb3_memret.tasks.mikasa.camera_experts import camera_expert

    task = make_task("RememberColor3-VLA-v0")
    env = harness.make_env(task.name)
    gate = SensorGate.of(env)
    assert SensorGate.of(env) is gate  # installed once
    renders, base_only = Counter(), Counter()
    render = gate._render

    def counted(*args, **kwargs):
        renders[key] += 1
        base_only[key] += list(env.unwrapped.scene.sensors) == ["base_camera"]
        return render(*args, **kwargs)

    gate._render = counted
    outcomes = {}
    try:
        for condition in ("oracle", "written"):
            for every_step in (True, False):
                key = (condition, every_step)
                agent = MemoryAgent(task, task.expert(), condition, task.replan_every, render_every_step=every_step)
                agent.bind(env)
                agent.begin(0)
                result = harness.play_episode(env, agent, 5001)
                outcomes[key] = (result.success_once, result.episode_return, result.n_steps, agent.prompts)
        key = ("camera", False)  # the expert on the cameras reads them at its decisions until it placed every cube
        agent = MemoryAgent(task, camera_expert(task), "oracle", task.replan_every)
        agent.bind(env)
        agent.begin(0)
        camera = harness.play_episode(env, agent, 5001)
        assert set(env.unwrapped.scene.sensors) == {"base_camera", "hand_camera"}  # narrowed for a render only
        gate.open, gate.cameras = True, frozenset({"side_camera"})
        with pytest.raises(ValueError, match=r"no camera \['side_camera'\] to render; the env's cameras are "):
            gate._sensor_data()
    finally:
        env.close()
    for condition in ("oracle", "written"):
        assert outcomes[condition, True] == outcomes[condition, False]
    steps = outcomes["oracle", True][2]
    assert renders["oracle", True] == steps + 1 and renders["oracle", False] == 1
    decisions = -(-camera.n_steps // task.replan_every)
    assert camera.success_once and 1 < renders["camera", False] < 1 + decisions
    assert task.perception_window(env) == 6
    assert renders["written", False] == 1 + 5 and renders["written", True] == steps + 1
    assert base_only["written", False] == 5 and base_only["written", True] == base_only["camera", False] == 0


OWN_TASK = '''from sb3_memret.tasks.mikasa.remember.color import RememberColorTask


class MyColour(RememberColorTask):
    def __init__(self):
        super().__init__("RememberColor3-VLA-v0")


class Elsewhere(MyColour):
    name = "MyOwnEnv-v0"

    def __init__(self):
        super().__init__()
        self.name = "MyOwnEnv-v0"
'''


def test_a_task_of_ones_own_plays_the_benchmark_under_the_env_id_it_names(tmp_path, monkeypatch):
    """``--tasks module:Class``: the class plays the MIKASA env its name gives, its row names the class, and a
    resumed run must name it again; a class naming an env the benchmark does not hold is refused in one line."""
    (tmp_path / "mycolour.py").write_text(OWN_TASK)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))  # for the episode workers
    out = tmp_path / "run"
    args = ["benchmark", "mikasa", "--conditions", "oracle", "--episodes", "1", "--seeds", "dev", "--workers", "1",
            "--no-progress", "--out", str(out)]
    result = CliRunner().invoke(main, [*args, "--tasks", "mycolour:MyColour"])
    assert result.exit_code == 0, result.output
    row = json.loads((out / "results.json").read_text())["tasks"]["RememberColor3-VLA-v0"]
    assert row["task_class"] == "mycolour:MyColour" and row["conditions"]["oracle"]["successes"] == [True]
    again = CliRunner().invoke(main, [*args, "--tasks", "RememberColor3-VLA-v0"])
    assert again.exit_code == 2 and "task_classes" in again.output  # played by another task: not resumed
    refused = CliRunner().invoke(main, [*args, "--tasks", "mycolour:Elsewhere"])
    assert refused.exit_code == 2 and "'MyOwnEnv-v0'" in refused.output and "Traceback" not in refused.output


def test_a_table_names_the_weights_it_played_and_each_file_s_sha256(tmp_path):
    import hashlib
    from types import SimpleNamespace

    from sb3_memret.benchmark.runner import controller_record
    from sb3_memret.controllers.shipped import CHECKPOINTS

    (tmp_path / "config.json").write_text("{}")
    (tmp_path / "model.safetensors").write_bytes(b"weights")
    local = SimpleNamespace(checkpoint=tmp_path, spec=SimpleNamespace(needs_images=True, harness_inputs=True))
    record = controller_record("learned", local)
    assert record["checkpoint"] == str(tmp_path.resolve()) and not record["privileged"]
    assert record["checkpoint_files_sha256"] == {"config.json": hashlib.sha256(b"{}").hexdigest(),
                                                 "model.safetensors": hashlib.sha256(b"weights").hexdigest()}
    shipped = CHECKPOINTS / "mikasa-multitask-camera"
    assert controller_record("learned", SimpleNamespace(checkpoint=shipped, spec=local.spec))["checkpoint"] == \
        "shipped: mikasa-multitask-camera"
    scripted = controller_record("scripted", SimpleNamespace(spec=SimpleNamespace(needs_images=False,
                                                                                    harness_inputs=False)))
    assert scripted["privileged"] and "checkpoint" not in scripted and "detector" in scripted["reads"]
    joints = controller_record("learned", SimpleNamespace(spec=SimpleNamespace(needs_images=True, harness_inputs=False)))
    assert joints["privileged"] and "joint positions and velocities" in joints["reads"]  # a camera policy on qvel


def test_episodes_that_changed_code_played_are_named_before_the_run(tmp_path, monkeypatch, capsys):
    """A folder whose logged episodes changed code played says so, once per kind, before it plays: those of the
    tasks this run asks for are played again; the others drop out of the table until a run asks for them."""
    from sb3_memret.benchmark import runner
    from sb3_memret.cli.benchmark import _say_outdated

    run = _plan(episodes=2)
    records = [_record("A-VLA-v0", "oracle", 5000, True, task_sha256="old task code"),
               _record("A-VLA-v0", "oracle", 5001, True, task_sha256="old task code"),
               _record("A-VLA-v0", "oracle", 5001, True),  # played again since: not outdated
               _record("B-VLA-v0", "none", 5000, False, controller_sha256="old controller"),
               {**_record("B-VLA-v0", "none", 5001, False, controller_sha256="old"), "error": "RuntimeError"},
               _record("C-VLA-v0", "none", 5000, False, controller_sha256="old")]  # refused here: not counted
    assert runner.outdated(run, records) == {"A-VLA-v0": 1, "B-VLA-v0": 1}

    with (tmp_path / runner.EPISODES_FILE).open("w") as f:
        f.writelines(json.dumps(r) + "\n" for r in records)
    only_b = Plan(run.protocol, [_row("B-VLA-v0", "Spatial")], ["none", "oracle"],
                  controllers={"B-VLA-v0": run.controllers["B-VLA-v0"]},
                  task_digests={"B-VLA-v0": run.task_digests["B-VLA-v0"]}, replan_every={"B-VLA-v0": 4})
    monkeypatch.setattr(runner, "widened", lambda plan, out: run)  # the folder's table: A, B and C
    monkeypatch.setattr(runner, "play_units", lambda *args, **kwargs: iter(()))
    heard = []
    runner.run_benchmark(only_b, tmp_path, on_outdated=lambda stale, replayed: heard.append((stale, replayed)))
    assert heard == [({"A-VLA-v0": 1, "B-VLA-v0": 1}, {"B-VLA-v0"})]

    _say_outdated(tmp_path, *heard[0])
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2
    assert "1 logged episodes of B-VLA-v0" in lines[0] and "played again" in lines[0]
    assert "1 logged episodes of A-VLA-v0" in lines[1] and "until a run asks for them" in lines[1]


def test_every_task_that_runs_here_has_hyperparameters_for_its_learner():
    """`benchmark learners` trains each task on its zoo section (a -Long variant is served by its short task's
    learner): a runnable task without one is refused, and its recall cell with it (GatherAndRecall 3-9 were)."""
    from sb3_memret.benchmark.agent import short_variant
    from sb3_memret.tasks import make_task
    from sb3_memret.training.config import load_task_config

    lacking = []
    for row in select_tasks("all", None):
        try:
            make_task(row.env_id)
        except (ValueError, FileNotFoundError, ImportError):  # refused here with its reason (the YCB mug)
            continue
        try:
            load_task_config(row.env_id)
        except (ValueError, FileNotFoundError):
            if short_variant(row.env_id) is None:
                lacking.append(row.env_id)
                continue
            load_task_config(short_variant(row.env_id))
    assert lacking == []
