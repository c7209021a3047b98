"""A run's table in MIKASA-Robo-VLA's own result layout, read back with the benchmark's own summary."""

import json
import math

from sb3_memret.benchmark.mikasa_results import MIKASA_DIR, mikasa_task_results, write_mikasa_results


def _cell(successes, complete=True):
    return {"episodes": len(successes), "seeds": [4242424242 + i for i in range(len(successes))],
            "successes": successes, "returns": [1.0 if s else 0.25 for s in successes],
            "episode_lengths": [40 if s else 90 for s in successes], "success": sum(successes) / len(successes),
            "complete": complete}


def _content():
    protocol = {"benchmark": "MIKASA-Robo-VLA", "control_mode": "pd_ee_delta_pose", "obs_mode": "rgb",
                "wrapper_chain": "apply_mikasa_vla_wrappers(include_overlays=False)", "seed_set": "protocol",
                "conditions": ["none", "oracle"]}
    controller = {"name": "scripted", "sha256": "ab" * 32, "reads": "a simulated object detector", "privileged": True}
    return {"protocol": protocol, "privileged_upper_bound": True, "tasks": {
        "RememberColor3-VLA-v0": {"split": "short", "memory_type": "Object", "controller": controller,
                                  "conditions": {"none": _cell([True, False, False, False]),
                                                 "oracle": _cell([True, True, True, False])}},
        "TakeItBack-VLA-v0": {"split": "short", "memory_type": "Spatial", "controller": controller,
                              "conditions": {"none": _cell([False, False]), "oracle": _cell([True], complete=False)}},
        "ShellGameTouch-VLA-v0": {"split": "short", "memory_type": "Spatial", "refused": "the YCB mug"}}}


def test_each_complete_cell_is_an_evaluate_task_result_and_partial_ones_are_left_out():
    results = mikasa_task_results(_content())
    assert [r["env_id"] for r in results["none"]] == ["RememberColor3-VLA-v0", "TakeItBack-VLA-v0"]
    assert [r["env_id"] for r in results["oracle"]] == ["RememberColor3-VLA-v0"]  # TakeItBack's has not finished
    r = results["oracle"][0]
    assert r["split"] == "Short" and r["sr"] == 0.75 and r["n_episodes"] == 4 and r["start_seed"] == 4242424242
    assert r["mean_return"] == (3 * 1.0 + 0.25) / 4 and r["episode_lengths"] == [40, 40, 40, 90]
    assert r["action_chunk_size"] == 1 and r["model"]["privileged_upper_bound"] and r["model"]["condition"] == "oracle"


def test_the_layout_is_written_by_mikasa_s_own_writer_and_its_summary_reads_back(tmp_path):
    from mikasa_robo_suite.vla.benchmarking import summarize_task_results

    folders = write_mikasa_results(tmp_path, _content())
    assert folders == [tmp_path / MIKASA_DIR / "none", tmp_path / MIKASA_DIR / "oracle"]
    none = tmp_path / MIKASA_DIR / "none"
    assert sorted(p.name for p in none.iterdir()) == ["RememberColor3-VLA-v0.json", "TakeItBack-VLA-v0.json",
                                                      "summary.json"]
    per_task = [json.loads((none / f"{env_id}.json").read_text())
                for env_id in ("RememberColor3-VLA-v0", "TakeItBack-VLA-v0")]
    summary = json.loads((none / "summary.json").read_text())
    assert summary == summarize_task_results(per_task)
    assert math.isclose(summary["sr_split"], (0.25 + 0.0) / 2)
    assert summary["sr_per_memory_type"] == {"Object": 0.25, "Spatial": 0.0}


def test_a_cell_written_before_results_held_returns_takes_them_from_the_episode_log(tmp_path):
    import pytest

    content = _content()
    cell = content["tasks"]["RememberColor3-VLA-v0"]["conditions"]["oracle"]
    del cell["returns"], cell["episode_lengths"]
    content["protocol"]["conditions"] = ["oracle"]
    with pytest.raises(ValueError, match=r"RememberColor3-VLA-v0 \(oracle\): no return logged for seeds"):
        write_mikasa_results(tmp_path, content)
    log = [{"env_id": "RememberColor3-VLA-v0", "condition": "oracle", "seed": seed, "success": ok,
            "return": 2.0, "steps": 30} for seed, ok in zip(cell["seeds"], cell["successes"])]
    write_mikasa_results(tmp_path, content, log)
    result = json.loads((tmp_path / MIKASA_DIR / "oracle" / "RememberColor3-VLA-v0.json").read_text())
    assert result["returns"] == [2.0] * 4 and result["episode_lengths"] == [30] * 4 and result["sr"] == 0.75
