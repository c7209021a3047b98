"""One memory learner across tasks (``MultiTaskVecEnv``, ``train recall --tasks``).

Two toy tasks from ``test_tasks``'s doors, each with a twin cue: the light's task needs "the light was red.", the
lamp's "the lamp was red.", and each bank also holds the other cue's fact with another colour. A retriever that
ignores the instruction (in the observation) can at best pick one cue for both tasks; one learner must read it.
"""

from __future__ import annotations

import dataclasses
import json
import textwrap
from typing import Any

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from sb3_memret.cli import main
from sb3_memret.training.config import TrainConfig, parse_section, resolve_task_settings
from sb3_memret.envs.multi_task import MultiTaskVecEnv, make_decision_vec_env, task_env_kwargs
from sb3_memret.envs.vec_env import recall_vec_env
from sb3_memret.evaluation.retrieval import evaluate_retrieval
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.policy.ppo import MemRetPPO
from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks import EnvFrame, Episode, register_task, task_names
from test_tasks import COLOURS, FACT, DoorsExpert, DoorsTask

TWINS = {"light": "lamp", "lamp": "light"}


class TwinWriter:
    """Writes the cue its task watches (``entity``) when the light flashes."""

    def __init__(self, entity: str):
        self.entity = entity
        self.relations = {"cue": (MemoryType.OTHER, "was")}

    def read(self, frame: EnvFrame) -> list[tuple[int, Any]]:
        return [(step, {("cue", self.entity): c}) for step, c in frame.timed_percepts() if c is not None]


class TwinCueTask(DoorsTask):
    """The doors, its cue named ``entity``; the bank also holds the twin cue's fact with another colour."""

    entity = "light"

    @property
    def _instruction(self) -> str:
        return f"go to the door of the {self.entity}."

    def writer(self, source: str = "seeded") -> TwinWriter:
        return TwinWriter(self.entity)

    def episode(self, frame: EnvFrame) -> Episode:
        return Episode(self.entity, frame.state["colour"], (((MemoryType.OTHER, self.entity, "was"),
                                                               frame.state["colour"]),))

    def seed_memories(self, frame, episode, rng, seeding: SeedingConfig, facts: bool = True) -> list[MemoryEntry]:
        fewer = dataclasses.replace(seeding, location_decoys=seeding.location_decoys - 1)
        twin_colour = str(rng.choice([c for c in COLOURS if c != episode.group]))
        return [*super().seed_memories(frame, episode, rng, fewer, facts),
                MemoryEntry.create(MemoryType.OTHER, TWINS[self.entity], "was", twin_colour, 0)]

    @property
    def prompt_template(self) -> PromptTemplate:
        return PromptTemplate(("go to the door of the light.", "go to the door of the lamp."), (FACT,))

    def instruction(self, episode: Episode) -> str:
        return self._instruction

    def oracle_facts(self, episode: Episode) -> list[str]:
        return [FACT.format(entity=self.entity, colour=episode.group)]

    def wrong_facts(self, episode: Episode) -> list[str]:
        return [FACT.format(entity=self.entity, colour=COLOURS[(COLOURS.index(episode.group) + 1) % 3])]

    def expert(self) -> DoorsExpert:
        expert = DoorsExpert()
        expert.spec = dataclasses.replace(expert.spec, prompt_template=self.prompt_template)
        return expert


class LightTask(TwinCueTask):
    name, entity = "twin-light-test", "light"


class LampTask(TwinCueTask):
    name, entity = "twin-lamp-test", "lamp"


for _task in (LightTask, LampTask):
    if _task.name not in task_names():
        register_task(_task.name, _task)

TASKS = [LightTask.name, LampTask.name]
ENV = {"tasks": TASKS, "controller": "scripted", "replan_every": 4, "location_decoys": 3, "capacity": 4}


@pytest.fixture
def venv(encoder):
    env = make_decision_vec_env(1, {**ENV, "encoder": encoder}, seed=0)
    yield env
    env.close()


def test_the_tasks_envs_are_one_batch_each_reporting_its_task(venv):
    obs = venv.reset()
    assert obs["memories"].shape == (2, 4, 384) and venv.num_envs == 2
    inner = venv.venv
    assert isinstance(inner, MultiTaskVecEnv) and inner.task_names == TASKS
    assert not np.allclose(obs["instruction"][0], obs["instruction"][1])  # the instruction tells them apart
    slots = [memory.true_slot() for part in inner.parts for memory in part.memories]
    _, _, _, infos = venv.step(np.array(slots)[:, None])
    assert [info["group"] for info in infos] == TASKS
    assert all(info["task_group"] in COLOURS and info["retrieved_true"] for info in infos)
    assert inner.seed(7) == [7, 8]


def test_held_out_seeds_and_task_seeds_go_to_each_tasks_envs(venv):
    inner = venv.venv
    assert inner.held_out_seed_blocks([2, 2], "development") is None  # the doors have no seed sets of their own
    with pytest.raises(ValueError, match="unknown held-out seed kind 'test'"):
        inner.held_out_seed_blocks([1, 1], "test")
    inner.set_task_seeds([[11], [12]])
    venv.reset()
    assert [part.episode_task_seeds[0] for part in inner.parts] == [11, 12]
    with pytest.raises(ValueError, match="task seeds for each of the 2 envs"):
        inner.set_task_seeds([[1]])


def test_tasks_whose_spaces_differ_cannot_share_a_learner(encoder):
    one = {key: value for key, value in ENV.items() if key != "tasks"}
    light = recall_vec_env(1, **{**one, "task": LightTask.name, "encoder": encoder})
    lamp = recall_vec_env(1, **{**one, "task": LampTask.name, "capacity": 5, "encoder": encoder})
    with pytest.raises(ValueError, match="differ in observation_space .* same capacity, k"):
        MultiTaskVecEnv([light, lamp])
    with pytest.raises(ValueError, match="two or more tasks"):
        MultiTaskVecEnv([light])
    light.close()
    lamp.close()


def test_one_learner_reads_the_instruction_to_serve_both_tasks(venv):
    """PPO learns, from each task's own reward, to retrieve the light's fact in one task and the lamp's in the
    other; before training, greedy retrieval cannot be right in both."""
    model = MemRetPPO(env=venv, n_steps=64, batch_size=32, gae_lambda=0.7, learning_rate=1e-3, seed=0)
    before = evaluate_retrieval(model, venv, 20, seed=1000)
    model.learn(3072)  # 24 of 24 seeds at 100% from 1536 steps on (the advantage floor keeps them there)
    after = evaluate_retrieval(model, venv, 20, seed=1000)
    assert after.greedy_accuracy >= 0.9 > before.greedy_accuracy
    assert after.episodes_per_group == {LightTask.name: 10, LampTask.name: 10}
    assert after.success[LightTask.name] >= 0.9 and after.success[LampTask.name] >= 0.9


def test_a_tasks_list_validates_and_takes_each_tasks_own_settings():
    section = {"n_timesteps": 8, "env_kwargs": {"tasks": ["InterceptSlow-VLA-v0", "RememberColor3-VLA-v0"],
                                                "capacity": 6, "k": 1}}
    config = resolve_task_settings(parse_section(section, "multitask"))
    own = config.env_kwargs["tasks"]
    assert own["InterceptSlow-VLA-v0"] == {"mode": "recall", "replan_every": 4, "location_decoys": 5,
                                           "success_bonus": 1.0}
    assert "success_bonus" not in own["RememberColor3-VLA-v0"] and config.task_names == list(own)
    per_task = task_env_kwargs(config.env_kwargs)
    assert per_task["InterceptSlow-VLA-v0"]["task"] == "InterceptSlow-VLA-v0" and \
        per_task["InterceptSlow-VLA-v0"]["capacity"] == 6
    for tasks, message in ((["drawer"], "two or more distinct tasks"), (["drawer", "nope"], "unknown task 'nope'"),
                           ({"drawer": {"capacity": 3}, "doors-test": {}}, "unknown key 'capacity'")):
        with pytest.raises(ValueError, match=message):
            parse_section({"n_timesteps": 8, "env_kwargs": {"tasks": tasks}}, "multitask")
    with pytest.raises(ValueError, match="sets both task and tasks"):
        parse_section({"n_timesteps": 8, "env_kwargs": {"task": "drawer", "tasks": ["drawer", "doors-test"]}}, "m")
    assert TrainConfig("drawer", {"n_timesteps": 1}).task_names == ["drawer"]


CONFIG = """
multitask:
  n_timesteps: 32
  n_envs: 1
  n_steps: 8
  batch_size: 8
  n_epochs: 1
  env_kwargs:
    capacity: 4
    location_decoys: 3
    replan_every: 4
"""


def test_train_across_tasks_from_the_command_line_resumes_and_serves_the_benchmark(tmp_path):
    from sb3_memret.benchmark.agent import MemoryLearner
    from sb3_memret.benchmark.learners import learner_tasks

    config, run, runner = tmp_path / "multi.yml", tmp_path / "run", CliRunner()
    config.write_text(textwrap.dedent(CONFIG))
    args = ["train", "recall", "--config", str(config), "--out", str(run), "--eval-episodes", "2", "--eval-every",
            "2", "--no-progress"]
    result = runner.invoke(main, [*args, "--tasks", ",".join(TASKS), "--timesteps", "16"])
    assert result.exit_code == 0, result.output
    saved = yaml.safe_load((run / "config.yml").read_text())["multitask"]["env_kwargs"]
    assert list(saved["tasks"]) == TASKS and "task" not in saved
    result = runner.invoke(main, ["train", "recall", "--out", str(run), "--resume", "--timesteps", "32",
                                  "--no-progress", "--eval-episodes", "2"])
    assert result.exit_code == 0, result.output
    assert "32 decisions" in result.output
    assert learner_tasks(run / "final_model.zip") == TASKS
    learner = MemoryLearner(run / "final_model.zip", "scripted", LampTask.name)
    assert learner.settings["task"] == LampTask.name and learner.settings["capacity"] == 4
    with pytest.raises(ValueError, match="not trained on 'doors-test'"):
        MemoryLearner(run / "final_model.zip", "scripted", "doors-test")


def test_eval_and_trace_play_a_learner_across_tasks_one_named_task_at_a_time(tmp_path):
    config, run, runner = tmp_path / "multi.yml", tmp_path / "run", CliRunner()
    config.write_text(textwrap.dedent(CONFIG))
    result = runner.invoke(main, ["train", "recall", "--config", str(config), "--out", str(run), "--tasks",
                                  ",".join(TASKS), "--timesteps", "16", "--eval-episodes", "2", "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "--task ID (one of its tasks)" in result.output and "sb3-memret report" not in result.output
    model = str(run / "final_model.zip")
    for args, message in ((["trace", model], "is a learner across 2 tasks and --task names none"),
                          (["eval", model, "--task", "doors-test"], "was not trained on 'doors-test'"),
                          (["report", str(run)], "a learner across tasks")):
        refused = runner.invoke(main, args)
        assert refused.exit_code == 2 and message in refused.output, refused.output
        assert "Traceback" not in refused.output
    traced = runner.invoke(main, ["trace", model, "--task", LampTask.name, "--json"])
    assert traced.exit_code == 0, traced.output
    trace, = json.loads(traced.stdout)
    assert "lamp" in trace["instruction"] and any(row["true"] for row in trace["rows"])
    evaluated = runner.invoke(main, ["eval", model, "--task", LightTask.name, "--episodes", "2", "--json"])
    assert evaluated.exit_code == 0, evaluated.output
    played = json.loads(evaluated.stdout)["episodes_per_group"]  # one task's episodes, grouped by its cue's colour
    assert sum(played.values()) == 2 and set(played) <= set(COLOURS)


def test_bad_task_lists_are_one_line_errors(tmp_path):
    runner = CliRunner()
    for args, message in ((["--tasks", "drawer"], "two or more distinct tasks"),
                          (["--tasks", "drawer,nope"], "unknown task 'nope'"),
                          (["--task", "drawer", "--tasks", ",".join(TASKS)], "--task) or several (--tasks), not both")):
        result = runner.invoke(main, ["train", "recall", *args, "--out", str(tmp_path / "x")])
        assert result.exit_code == 2 and message in result.output, result.output
        assert "Traceback" not in result.output


def test_a_split_lists_the_tasks_that_run_here_and_says_why_not_the_others():
    from sb3_memret.benchmark.manifest import select_tasks
    from sb3_memret.benchmark.runner import split_tasks
    from sb3_memret.cli.training import parse_tasks

    names, refused = split_tasks("short")
    assert parse_tasks("mikasa:short") == names
    assert "RememberColor3-VLA-v0" in names and "InterceptSlow-VLA-v0" in names
    assert sorted(names + list(refused)) == sorted(row.env_id for row in select_tasks("short"))
    assert "TimedTransferEasy-VLA-v0" in names
    assert "mug" in refused["ShellGameTouch-VLA-v0"]
    with pytest.raises(Exception, match="unknown split 'tiny'"):
        parse_tasks("mikasa:tiny")
