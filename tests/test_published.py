"""The published figures the benchmark report puts beside a run's own."""

from __future__ import annotations

import pytest

from sb3_memret.benchmark.published import PUBLISHED, published_figures, published_section


def test_every_published_figure_names_its_task_its_source_and_how_it_was_read():
    figures = published_figures()
    assert {f.vla_task for f in figures} == {f"RememberColor{n}-VLA-v0" for n in (3, 5, 9)}
    for f in figures:
        assert f.task == f.vla_task.replace("-VLA-v0", "-v0")  # the older tasks, never passed off as the VLA ones
        assert 0 <= f.success <= 1 and f.episodes > 0 and "arXiv:" in f.source
        assert f.read_from in ("paper table", "quoted by others")
    methods = {f.method for f in figures}
    assert {"Octo-small (K=4)", "π0 (K=4)", "MemoryVLA"} <= methods
    assert all(sum(f.method == m for f in figures) == 3 for m in methods)  # one figure per task each


def test_the_report_section_covers_only_the_tasks_a_run_shares():
    lines = published_section({"RememberColor5-VLA-v0": "96% (48/50)", "TakeItBack-VLA-v0": "100% (50/50)"},
                              "learned", "recall")
    table = [line for line in lines if line.startswith("|")]
    assert table[0] == "| method | RememberColor5 | read from | source |"
    assert table[2].startswith("| sb3-memret, learned controller, recall (this run, -VLA-v0) | 96% (48/50) |")
    assert any(line.startswith("| π0 (K=4) | 22% ± 4 | paper table |") for line in table)
    assert any("RememberColor5-v0: a 60-step horizon" in line for line in lines)
    assert published_section({"TakeItBack-VLA-v0": "100%"}, "scripted", "recall") == []


def test_a_run_of_no_memory_condition_shows_the_published_rows_alone():
    """A run of none and wrong only has no memory method to set beside them: the report's row is left out rather than
    one of those conditions passed off as ours."""
    from sb3_memret.benchmark.report import render_report

    cell = {"episodes": 1, "seeds": [5000], "successes": [False], "success": 0.0, "complete": True}
    content = {"protocol": {"benchmark": "MIKASA-Robo-VLA", "harness": "h", "wrapper_chain": "w", "control_mode": "c",
                            "obs_mode": "rgb", "metric": "success_once", "policy_inputs": ["rgb"], "episodes": 1,
                            "seed_set": "dev", "seeds": [5000], "controller": "learned", "replan_every": None,
                            "conditions": ["none", "wrong"]},
               "privileged_upper_bound": False,
               "tasks": {"RememberColor9-VLA-v0": {"split": "short", "memory_type": "Object", "replan_every": 4,
                                                   "controller": {"reads": "cameras"},
                                                   "conditions": {"none": cell, "wrong": cell}}}}
    report = render_report(content)
    assert "## Published figures beside ours" in report and "| π0 (K=4) |" in report
    assert "sb3-memret, learned controller" not in report
    content["protocol"]["conditions"] = ["none", "oracle", "wrong"]
    content["tasks"]["RememberColor9-VLA-v0"]["conditions"]["oracle"] = {**cell, "successes": [True], "success": 1.0}
    assert "| sb3-memret, learned controller, oracle (this run, -VLA-v0) | 100% (1/1) |" in render_report(content)


def test_a_controller_that_reads_the_simulator_is_a_privileged_upper_bound_kept_out_of_the_comparison():
    """A scripted expert reads object poses through a simulated detector: its report names it an upper bound, does
    not state the protocol's policy inputs as its inputs and sets no row of it beside the published methods."""
    from sb3_memret.benchmark.report import render_report

    cell = {"episodes": 1, "seeds": [5000], "successes": [True], "success": 1.0, "complete": True}
    reads = "proprioception and a simulated object detector (objects in sight), beyond the protocol's policy inputs"
    content = {"protocol": {"benchmark": "MIKASA-Robo-VLA", "harness": "h", "wrapper_chain": "w", "control_mode": "c",
                            "obs_mode": "rgb", "metric": "success_once", "policy_inputs": ["rgb", "proprio",
                                                                                           "instruction"],
                            "episodes": 1, "seed_set": "dev", "seeds": [5000], "controller": "scripted",
                            "replan_every": None, "conditions": ["oracle"]},
               "privileged_upper_bound": True,
               "tasks": {"RememberColor9-VLA-v0": {"split": "short", "memory_type": "Object", "replan_every": 4,
                                                   "controller": {"reads": reads, "privileged": True},
                                                   "conditions": {"oracle": cell}}}}
    report = render_report(content)
    assert "scripted controller, a privileged upper bound" in report.splitlines()[0]
    assert "Policy inputs:" not in report and "not a protocol entry" in report
    assert "## Published figures beside ours" not in report and "sb3-memret, scripted controller" not in report
    del content["privileged_upper_bound"]  # a results file from before the flag: every controller then read more
    content["tasks"]["RememberColor9-VLA-v0"]["controller"] = {"reads": "cameras and proprioception"}
    assert "Policy inputs:" not in render_report(content)  # (a camera policy's joint velocities, beyond the 7-D)
    content["privileged_upper_bound"] = False  # a controller on the harness's inputs alone
    assert "- Policy inputs: rgb, proprio, instruction" in render_report(content)


def test_a_figure_that_is_not_a_fraction_is_refused(tmp_path):
    bad = tmp_path / "published.csv"
    rows = PUBLISHED.read_text().splitlines()
    bad.write_text("\n".join([rows[0], rows[1].replace(",0.45,", ",45,")]) + "\n")
    with pytest.raises(ValueError, match="Octo-small .K=4. on RememberColor3-v0 has success 45.0"):
        published_figures(bad)
