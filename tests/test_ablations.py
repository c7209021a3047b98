"""Controller ablations: the drawer's table specs, the Wilson interval and the result tables (no simulator),
then the prompt and memory-count ablations played by the scripted controller on the real simulator."""

import csv
import io
import json
from collections import Counter

import pytest

from sb3_memret.analysis import ablations
from sb3_memret.analysis.ablations import AblationResult, CellResult, wilson_interval
from sb3_memret.tasks.ablations import AblationOptions, AblationSpec, Cell
from sb3_memret.evaluation.parallel import EpisodeJob
from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer import ablations as drawer_ablations
from sb3_memret.tasks.drawer.ablations import memcount_ablation, prompt_ablation, replan_ablation
from sb3_memret.controllers.prompts import parse_prompt
from sb3_memret.tasks.drawer.prompts import TEMPLATE, named_layer
from sb3_memret.evaluation.rollout import EpisodeResult

INSTRUCTION = "pick out the cube."
LAYER_COLUMNS = ("layer 1", "layer 2", "layer 3")
SEED = 1_000_000


def at(layer):
    return {"target_layer": layer}


def run_ablation(spec, controller, **kwargs):
    return ablations.run_ablation(spec, DrawerTask(), controller, **kwargs)


def oracle(layer, entity="cube"):
    return f"{INSTRUCTION} the {entity} is in drawer layer {layer}."


def by_position(spec):
    cells = {(c.row, c.column): c for c in spec.cells}
    assert len(cells) == len(spec.cells), "two cells share a (row, column)"
    return cells


# ------------------------------------------------------------------ specs


def test_replan_spec_is_oracle_per_layer_for_each_interval():
    spec = replan_ablation()
    intervals = (5, 8, 10, 12, 16, 20, 24, 28, 32)
    assert spec.rows == tuple(map(str, intervals))
    assert spec.columns == (*LAYER_COLUMNS, "overall") and spec.pooled_column == "overall"
    cells = by_position(spec)
    assert len(cells) == 27
    for interval in intervals:
        for layer in (1, 2, 3):
            cell = cells[str(interval), f"layer {layer}"]
            assert (cell.reset_options, cell.replan_every, cell.prompt) == (at(layer), interval, oracle(layer))
            assert named_layer(parse_prompt(cell.prompt, TEMPLATE)) == layer


@pytest.mark.parametrize("layer, wrong", [(1, 2), (2, 3), (3, 1)])
def test_prompt_spec_crosses_object_word_with_layer(layer, wrong):
    spec = prompt_ablation(layer)
    assert spec.columns == ("correct layer", "wrong layer") and spec.pooled_column is None
    correct_row, wrong_row, none_row = spec.rows
    assert "cube" in correct_row and "key" in wrong_row
    cells = by_position(spec)
    assert len(cells) == 5
    expected = {
        (correct_row, "correct layer"): oracle(layer),
        (correct_row, "wrong layer"): oracle(wrong),
        (wrong_row, "correct layer"): oracle(layer, "key"),
        (wrong_row, "wrong layer"): oracle(wrong, "key"),
    }
    for position, prompt in expected.items():
        assert cells[position].prompt == prompt
    (bare,) = [c for c in spec.cells if c.row == none_row]
    assert bare.prompt == INSTRUCTION
    for cell in spec.cells:
        assert cell.reset_options == at(layer)  # the cube never moves; only the prompt does
        parse_prompt(cell.prompt, TEMPLATE)


def test_memcount_spec_adds_memories_one_at_a_time():
    spec = memcount_ablation()
    assert len(spec.rows) == 3 and spec.columns == (*LAYER_COLUMNS, "overall") and spec.pooled_column == "overall"
    cells = by_position(spec)
    assert len(cells) == 9
    none_row, one_row, two_row = spec.rows
    for layer in (1, 2, 3):
        column = f"layer {layer}"
        assert cells[none_row, column].prompt == INSTRUCTION
        assert cells[one_row, column].prompt == oracle(layer)
        assert cells[two_row, column].prompt == oracle(layer) + " the robot is holding nothing."
        facts = parse_prompt(cells[two_row, column].prompt, TEMPLATE).facts
        assert len(facts) == 2 and int(facts[0].value("layer")) == layer
        assert [c.reset_options for c in spec.cells if c.column == column] == [at(layer)] * 3


def test_replan_interval_is_passed_to_every_cell():
    assert {c.replan_every for c in memcount_ablation(12).cells} == {12}
    assert {c.replan_every for c in memcount_ablation().cells} == {None}  # the task's
    assert {c.replan_every for c in prompt_ablation(1, replan_every=5).cells} == {5}


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: replan_ablation([]), r"\[\]"),
        (lambda: replan_ablation([0]), r"\[0\]"),
        (lambda: replan_ablation([8, -3]), r"-3"),
        (lambda: prompt_ablation(4), r"got 4"),
        (lambda: run_ablation(prompt_ablation(2), "scripted", episodes=0), r"got 0"),
    ],
    ids=["no-intervals", "zero-interval", "negative-interval", "layer-4", "zero-episodes"],
)
def test_bad_input_is_refused_naming_the_value(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_run_ablation_plays_each_cell_on_the_same_seeds(monkeypatch):
    """The job grid and how results are cut back into cells, with the simulator replaced."""
    calls = []

    def fake_run_jobs(controller, jobs, task, n_envs, render_backend, on_result, backend, ray_address):
        calls.append((controller, list(jobs), task.name, n_envs, render_backend))
        # succeed when the prompt names the cube's layer, on odd seeds only
        layer = [j.reset_options["target_layer"] for j in jobs]
        return [EpisodeResult(str(layer), j.seed, named_layer(parse_prompt(j.prompt, TEMPLATE)) == layer and j.seed % 2 == 1, 10)
                for j, layer in zip(jobs, layer)]

    monkeypatch.setattr(ablations, "run_jobs", fake_run_jobs)
    spec = prompt_ablation(2, replan_every=10)
    result = run_ablation(spec, "scripted", episodes=3, seed=7, n_envs=2)
    (controller, jobs, task, n_envs, backend), = calls
    assert (controller, task, n_envs, backend) == ("scripted", "drawer", 2, "none")
    assert jobs == [EpisodeJob(c.prompt, s, at(2), 10) for c in spec.cells for s in (7, 8, 9)]
    assert [(c.row, c.column) for c in result.cells] == [(c.row, c.column) for c in spec.cells]
    correct_row, wrong_row, none_row = spec.rows
    assert result.rate(correct_row, "correct layer") == pytest.approx(2 / 3)  # seeds 7 and 9
    assert result.rate(wrong_row, "correct layer") == pytest.approx(2 / 3)
    assert result.rate(correct_row, "wrong layer") == 0.0
    assert result.rate(none_row, "wrong layer") == 0.0
    assert result.rate(none_row, "correct layer") is None
    assert all(c.episodes == 3 for c in result.cells)
    assert (result.episodes, result.seed, result.controller) == (3, 7, "scripted")


# ------------------------------------------------------------------ Wilson interval


@pytest.mark.parametrize("k, n", [(0, 1), (1, 3), (5, 10), (9, 17), (0, 17), (17, 17), (16, 17),
                                  (0, 11), (6, 6), (100, 100)])
def test_wilson_interval_contains_the_rate_within_unit_interval(k, n):
    low, high = wilson_interval(k, n)
    assert 0.0 <= low <= k / n <= high <= 1.0
    assert low < high


def test_wilson_interval_at_the_extremes_is_one_sided():
    low, high = wilson_interval(0, 17)
    assert low == 0.0 and 0.0 < high < 0.5
    low, high = wilson_interval(17, 17)
    assert high == 1.0 and 0.5 < low < 1.0


def test_wilson_interval_narrows_with_more_episodes():
    widths = [wilson_interval(n // 2, n) for n in (10, 40, 160)]
    widths = [high - low for low, high in widths]
    assert widths[0] > widths[1] > widths[2]


def test_wilson_interval_needs_an_episode_and_a_possible_count():
    with pytest.raises(ValueError, match="got 0"):
        wilson_interval(0, 0)
    with pytest.raises(ValueError, match=r"successes must be in \[0, 3\], got 4"):
        wilson_interval(4, 3)


# ------------------------------------------------------------------ result tables


@pytest.fixture
def hand_result():
    """Row 'a' fills every layer (1/2, 2/2, 0/2); row 'b' only layer 1 (1/1)."""
    counts = {("a", 1): (2, 1), ("a", 2): (2, 2), ("a", 3): (2, 0), ("b", 1): (1, 1)}
    cells = [CellResult(row, f"layer {layer}", oracle(layer), at(layer), 8, n, k) for (row, layer), (n, k) in counts.items()]
    spec = AblationSpec("test", "A test table", "condition", ("a", "b"), (*LAYER_COLUMNS, "overall"),
                        tuple(Cell(c.row, c.column, c.prompt, c.reset_options) for c in cells), pooled_column="overall")
    return AblationResult(spec, episodes=2, seed=SEED, controller="scripted", cells=cells)


def test_rate_of_cells_and_pooled_column(hand_result):
    assert hand_result.rate("a", "layer 1") == 0.5
    assert hand_result.rate("a", "layer 2") == 1.0
    assert hand_result.rate("a", "layer 3") == 0.0
    assert hand_result.rate("a", "overall") == 0.5  # 3 of 6 episodes
    assert hand_result.rate("b", "overall") == 1.0
    assert hand_result.rate("b", "layer 2") is None
    assert hand_result.rate("c", "overall") is None


def test_cell_result_success_and_interval():
    cell = CellResult("a", "layer 1", INSTRUCTION, at(1), 8, episodes=4, successes=1)
    assert cell.success == 0.25
    assert (cell.ci_low, cell.ci_high) == wilson_interval(1, 4)


def test_markdown_has_a_header_and_one_line_per_row(hand_result):
    lines = hand_result.to_markdown().splitlines()
    assert "| condition | layer 1 | layer 2 | layer 3 | overall |" in lines
    assert [line for line in lines if line.startswith("| a |")] == ["| a | 50% | 100% | 0% | 50% |"]
    assert [line for line in lines if line.startswith("| b |")] == ["| b | 100% | – | – | 100% |"]
    assert "A test table" in lines[0]
    for layer in (1, 2, 3):
        assert any(oracle(layer) in line for line in lines)


def test_csv_has_one_row_per_cell(hand_result):
    rows = list(csv.DictReader(io.StringIO(hand_result.to_csv())))
    assert len(rows) == len(hand_result.cells)
    for row, cell in zip(rows, hand_result.cells):
        assert (row["ablation"], row["row"], row["column"], row["prompt"]) == ("test", cell.row, cell.column, cell.prompt)
        assert (json.loads(row["reset_options"]), int(row["episodes"]), int(row["successes"])) == \
            (cell.reset_options, cell.episodes, cell.successes)
        assert float(row["success"]) == pytest.approx(cell.successes / cell.episodes)
        assert float(row["ci_low"]) <= float(row["success"]) <= float(row["ci_high"])


def test_dict_is_json_and_its_table_matches_rate(hand_result):
    data = json.loads(json.dumps(hand_result.to_dict()))
    assert data["ablation"] == "test" and data["rows"] == ["a", "b"]
    assert data["columns"] == [*LAYER_COLUMNS, "overall"]
    for row in ("a", "b"):
        for column in data["columns"]:
            assert data["table"][row][column] == hand_result.rate(row, column)
    assert [c["success"] for c in data["cells"]] == [c.success for c in hand_result.cells]


# ------------------------------------------------------------------ real simulator, scripted controller


def play(spec, n_envs):
    played = []
    result = run_ablation(spec, "scripted", episodes=1, seed=SEED, n_envs=n_envs,
                          on_episode=lambda job, outcome: played.append((job, outcome)))
    return result, played


def assert_called_once_per_episode(spec, played):
    expected = [(c.prompt, SEED, c.reset_options["target_layer"], c.replan_every) for c in spec.cells]
    assert Counter((job.prompt, job.seed, job.reset_options["target_layer"], job.replan_every)
                   for job, _ in played) == Counter(expected)
    for job, outcome in played:
        assert (outcome.group, outcome.seed) == (str(job.reset_options["target_layer"]), job.seed)


@pytest.fixture(scope="module")
def prompt_run():
    spec = prompt_ablation(2)
    return spec, *play(spec, n_envs=1)


@pytest.fixture(scope="module")
def memcount_run():
    spec = memcount_ablation()
    return spec, *play(spec, n_envs=2)


def test_scripted_controller_follows_the_layer_not_the_object_word(prompt_run):
    spec, result, _ = prompt_run
    correct_row, wrong_row, none_row = spec.rows
    assert result.rate(correct_row, "correct layer") == 1.0
    assert result.rate(wrong_row, "correct layer") == 1.0
    assert result.rate(correct_row, "wrong layer") == 0.0
    assert result.rate(wrong_row, "wrong layer") == 0.0
    assert result.rate(none_row, "wrong layer") == 0.0  # opens the top drawer; the cube is in layer 2
    assert result.rate(none_row, "correct layer") is None
    assert "| " + none_row + " | – | 0% |" in result.to_markdown().splitlines()
    for cell in result.cells:  # steps to success are kept for the successful episodes only
        assert len(cell.win_steps) == cell.successes
        assert (cell.median_steps is None) == (cell.successes == 0)
        assert all(0 < steps <= 400 for steps in cell.win_steps)  # the task's episode limit


def test_prompt_ablation_reports_every_episode_once(prompt_run):
    spec, _, played = prompt_run
    assert_called_once_per_episode(spec, played)


def test_memory_count_on_the_simulator_with_two_workers(memcount_run):
    spec, result, played = memcount_run
    none_row, one_row, two_row = spec.rows
    assert [result.rate(none_row, column) for column in LAYER_COLUMNS] == [1.0, 0.0, 0.0]
    assert result.rate(none_row, "overall") == pytest.approx(1 / 3)
    for row in (one_row, two_row):
        assert [result.rate(row, column) for column in (*LAYER_COLUMNS, "overall")] == [1.0] * 4
    assert_called_once_per_episode(spec, played)


def test_prompt_legend_lists_each_prompt_once_with_where_it_is_used():
    spec = replan_ablation()
    result = AblationResult(spec, 1, 0, "scripted", [CellResult(c.row, c.column, c.prompt, c.reset_options, c.replan_every,
                                                                1, 1, (200,)) for c in spec.cells])
    legend = result.to_markdown().split("Prompts:")[1].strip().splitlines()
    assert legend == [f"- layer {layer}: `pick out the cube. the cube is in drawer layer {layer}.`" for layer in (1, 2, 3)]
    assert "Median control steps to success: 5: 200 · 8: 200" in result.to_markdown()


def test_wording_spec_rewords_only_the_oracle_fact_and_waives_the_contract():
    spec = drawer_ablations.wording_ablation()
    assert spec.rows[0] == "the cube is in drawer layer L." and len(spec.cells) == 3 * len(drawer_ablations.WORDINGS)
    trained = [c for c in spec.cells if c.row == spec.rows[0]]
    assert [named_layer(parse_prompt(c.prompt, TEMPLATE)) for c in trained] == [1, 2, 3]
    for cell in spec.cells:
        assert not cell.check_prompt and cell.prompt.startswith("pick out the cube. ")
        if cell.row != spec.rows[0]:
            with pytest.raises(ValueError, match="matches no trained template"):
                parse_prompt(cell.prompt, TEMPLATE)
    assert "the cube is in the second drawer." in {c.prompt.removeprefix("pick out the cube. ") for c in spec.cells}


def test_wording_cells_reach_the_controller_unchecked(task_env):
    from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
    from conftest import drawer_episode

    prompt = "pick out the cube. the cube is in layer 3."
    with pytest.raises(ValueError, match="matches no trained template"):
        drawer_episode(task_env, ScriptedDrawerController(), prompt, seed=0, layer=1)
    # unchecked, the expert cannot parse it and falls back to its bare-prompt behaviour: the top drawer
    assert drawer_episode(task_env, ScriptedDrawerController(), prompt, seed=0, layer=1, check_prompt=False).success


def test_the_drawer_names_its_tables_and_builds_them_from_a_commands_options():
    tables = DrawerTask().ablations()
    assert sorted(tables) == ["memcount", "prompt", "replan", "wording"]
    assert {c.reset_options["target_layer"] for c in tables["prompt"](AblationOptions(group="3")).cells} == {3}
    assert [s.rows for s in (tables["replan"](AblationOptions(intervals=(4, 8))),)] == [("4", "8")]
    with pytest.raises(ValueError, match=r"the cube's drawer layer, one of \[1, 2, 3\]; got 'top'"):
        tables["prompt"](AblationOptions(group="top"))
