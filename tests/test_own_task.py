"""A task of one's own, as a new user writes it: a module outside the package, named ``module:Class``, with its own
YAML. Its hyperparameters are found there, its run folder reads back (``eval``, ``train --resume``), and a ``--task``
that names no task ends in one line that says what would be accepted.

The user's module lives in a temporary folder on ``sys.path``: the toy doors task of ``test_tasks`` (the cheapest task
that goes through the real decision env) under a name of its own.
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from sb3_memret.cli import main
from sb3_memret.training.config import load_task_config
from sb3_memret.tasks import make_task

USER_MODULE = '''
"""My doors: the test suite's toy task under a name of my own."""

from test_tasks import DoorsTask


class MyDoorsTask(DoorsTask):
    name = "my-doors"
    replan_every = 4  # the expert's chunk: commands and configs that name no interval take it
'''
USER_CONFIG = """
my-doors:                 # the task's config_key: its name
  n_timesteps: 16
  n_envs: 1
  n_steps: 8
  batch_size: 8
  n_epochs: 1
  env_kwargs:
    task: my_doors:MyDoorsTask
    capacity: 4
    location_decoys: 3
"""
SPEC = "my_doors:MyDoorsTask"


@pytest.fixture
def user_folder(tmp_path, monkeypatch) -> Path:
    """The user's folder, on ``sys.path`` (as PYTHONPATH puts it): ``my_doors.py`` and ``my.yml``."""
    (tmp_path / "my_doors.py").write_text(textwrap.dedent(USER_MODULE))
    (tmp_path / "my.yml").write_text(USER_CONFIG)
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


def _one_line_error(result, *fragments: str) -> None:
    """A usage error: exit status 2, one line, no traceback, naming every fragment."""
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error:") and "Traceback" not in result.output, result.output
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_the_users_yaml_gives_a_task_of_ones_own_its_hyperparameters(user_folder):
    config = load_task_config(SPEC, user_folder / "my.yml")
    assert config.env_kwargs["task"] == SPEC and config.n_timesteps == 16
    with pytest.raises(ValueError, match="no hyperparameters for task 'my_doors:MyDoorsTask'.*no section for env id "
                                         "'my-doors'.*pass --config FILE, a YAML with a section 'my-doors'"):
        load_task_config(SPEC)


def test_a_run_of_a_task_of_ones_own_trains_evaluates_and_resumes(user_folder):
    runner, run = CliRunner(), user_folder / "run"
    result = runner.invoke(main, ["train", "recall", "--task", SPEC, "--config", str(user_folder / "my.yml"),
                                  "--out", str(run), "--eval-episodes", "2", "--eval-every", "1", "--no-progress"])
    assert result.exit_code == 0, result.output
    assert yaml.safe_load((run / "config.yml").read_text())["my-doors"]["env_kwargs"]["task"] == SPEC
    assert (run / "final_model.zip").is_file()

    result = runner.invoke(main, ["eval", str(run / "final_model.zip"), "--episodes", "2", "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output.strip().splitlines()[-1])
    assert report["episodes"] == 2 and set(report["success"]) <= {"overall", "red", "green", "blue"}

    result = runner.invoke(main, ["train", "recall", "--resume", "--out", str(run), "--timesteps", "24",
                                  "--eval-episodes", "2", "--no-progress"])
    assert result.exit_code == 0, result.output
    assert json.loads((run / "summary.json").read_text())["num_timesteps"] == 24


def test_commands_replan_at_the_tasks_own_interval_unless_told(user_folder):
    """``rollout`` without ``--replan-every`` takes the task's (4: the doors expert's chunk, so 8 would be refused)."""
    assert (make_task("drawer").replan_every, make_task("RememberColor3-VLA-v0").replan_every) == (8, 4)
    runner = CliRunner()
    result = runner.invoke(main, ["rollout", "--task", SPEC, "--episodes", "3", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output.strip().splitlines()[-1])["success"]["overall"] == 1.0
    result = runner.invoke(main, ["rollout", "--task", SPEC, "--episodes", "1", "--replan-every", "8"])
    assert result.exit_code == 2 and "replan_every must be in [1, 4] (the chunk length), got 8" in result.output


def _rollout(runner: CliRunner, condition: str, episodes: int = 6) -> dict:
    result = runner.invoke(main, ["rollout", "--task", SPEC, "--condition", condition, "--episodes", str(episodes),
                                  "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.output.strip().splitlines()[-1])


def test_the_written_condition_checks_the_writer_end_to_end(user_folder, monkeypatch):
    """``rollout --condition written``: the prompt carries what the task's writer wrote from the frames (the light,
    seen at the reset frame's percept), so it matches oracle episode for episode while the writer reads right, and
    fails where oracle succeeds once it misreads."""
    import test_tasks

    runner = CliRunner()
    oracle, written = _rollout(runner, "oracle"), _rollout(runner, "written")
    assert oracle["success"]["overall"] == 1.0
    assert {k: written[k] for k in ("seeds", "success", "median_steps_to_success")} == \
        {k: oracle[k] for k in ("seeds", "success", "median_steps_to_success")}

    def misread(self, frame):  # the next colour round: a broken reader
        colours = test_tasks.COLOURS
        return [(step, {("light", "light"): colours[(colours.index(c) + 1) % 3]})
                for step, c in frame.timed_percepts() if c is not None]

    monkeypatch.setattr(test_tasks.LightWriter, "read", misread)
    assert _rollout(runner, "written")["success"]["overall"] == 0.0
    assert _rollout(runner, "oracle")["success"]["overall"] == 1.0  # the writer is all that changed


def test_the_written_condition_reads_a_cue_shown_between_two_decisions():
    """The light of ``LateLightTask`` flashes at control step 3, inside the first chunk: only a per-step percept sees
    it, and ``WrittenFacts`` hands it to the second decision's prompt."""
    from test_tasks import COLOURS, DoorsExpert, LateLightTask

    from sb3_memret.evaluation.rollout import WrittenFacts, evaluate_task_condition, play_task_episodes

    class Recorded(WrittenFacts):
        def facts(self, decision: int) -> list[str]:
            self.seen.append(list(super().facts(decision)))
            return self.seen[-1]

    task = LateLightTask()
    schedule = Recorded(task)
    schedule.seen = []
    result, = play_task_episodes(DoorsExpert(), task, [0], schedule, replan_every=4)
    assert schedule.seen[0] == [] and schedule.seen[1] == [f"the light was {result.group}."] and result.success
    written = evaluate_task_condition(DoorsExpert(), "written", task, 12, replan_every=4)
    assert all(r.success for r in written) and {r.group for r in written} == set(COLOURS)


MY_CUE_MODULE = '''
"""My RememberColor: MIKASA's RememberColor3 with an instruction worded my way."""

from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.mikasa import COLOUR_NAMES, ControllerObservation, MikasaCueTask, read_cue_colour

INSTRUCTION = "look at the cube, remember its colour, then touch the cube of that colour."


class MyCueTask(MikasaCueTask):
    field, detector_key, truth_attribute = "colour", "cube", "true_color_indices"
    cue_entity, cue_relation, cue_fact = "shown cube", "was", "the shown cube was {colour}."
    instruction_text, template = INSTRUCTION, PromptTemplate((INSTRUCTION,), ("the {entity} was {colour}.",))
    vocabulary, observation_wrapper = COLOUR_NAMES, ControllerObservation

    def __init__(self, env_id: str = "RememberColor3-VLA-v0"):
        super().__init__(env_id, 3)

    def read_cue(self, rgb):
        return read_cue_colour(rgb, self.n_words)
'''


def test_a_cue_task_of_ones_own_is_built_from_the_public_mikasa_parts(user_folder):
    """A RememberColor-like task written only with ``sb3_memret.tasks.mikasa``'s exports: its prompts follow its own
    wording, its expert obeys them, and as it is named by MIKASA's env id the shipped section of that id (for the
    registered task) is refused for it with the way out."""
    from sb3_memret.controllers.prompts import build_prompt
    from sb3_memret.tasks import Episode
    from sb3_memret.tasks.mikasa import ScriptedTouchController

    (user_folder / "my_cue.py").write_text(textwrap.dedent(MY_CUE_MODULE))
    task = make_task("my_cue:MyCueTask")
    episode = Episode("shown cube", "lime", ())
    prompt = build_prompt(task.instruction(episode), task.oracle_facts(episode), task.expert().spec.prompt_template)
    assert prompt == "look at the cube, remember its colour, then touch the cube of that colour. the shown cube was lime."
    assert isinstance(task.expert(), ScriptedTouchController) and task.words == ("red", "lime", "blue")
    assert task.replan_every == 4 and task.config_key == "RememberColor3-VLA-v0"
    result = CliRunner().invoke(main, ["train", "recall", "--task", "my_cue:MyCueTask", "--out",
                                       str(user_folder / "r")])
    _one_line_error(result, "section 'RememberColor3-VLA-v0' of the config is for task 'RememberColor3-VLA-v0', not "
                            "'my_cue:MyCueTask'", "pass --config FILE")


def test_a_task_of_ones_own_without_a_config_is_told_where_to_put_it(user_folder):
    result = CliRunner().invoke(main, ["train", "recall", "--task", SPEC, "--out", str(user_folder / "run")])
    _one_line_error(result, "no hyperparameters for task 'my_doors:MyDoorsTask'", "zoo_configs", "pass --config FILE",
                    "section 'my-doors'")


@pytest.mark.parametrize("task, fragments", [
    ("os.path:join", ["'os.path:join'", "os.path.join is a function, not a Task subclass",
                      "package.module:Class naming a sb3_memret.tasks.Task subclass"]),
    ("nosuchmodule:X", ["'nosuchmodule:X'", "No module named 'nosuchmodule'", "PYTHONPATH"]),
    ("sb3_memret.tasks:Task", ["Task() fails", "abstract", "whose __init__ needs no arguments"]),
])
def test_a_task_value_that_names_no_task_is_one_line(user_folder, task, fragments):
    runner = CliRunner()
    for args in (["rollout", "--task", task], ["train", "recall", "--task", task, "--out", str(user_folder / "r")]):
        _one_line_error(runner.invoke(main, args), "--task", *fragments)
    bad = user_folder / "bad.yml"
    bad.write_text(USER_CONFIG.replace(SPEC, task))
    result = runner.invoke(main, ["train", "recall", "--task", SPEC, "--config", str(bad), "--out",
                                  str(user_folder / "r")])
    _one_line_error(result, "--config", f"env_kwargs: task={task!r} is invalid", *fragments[1:])
