"""scripts/mikasa_table.py: the table's rows and the published figures beside them, and its refusals."""

import pytest


@pytest.fixture(scope="module")
def table(load_script):
    return load_script("mikasa_table")


def test_the_table_puts_each_task_row_and_the_published_systems_beside_our_recall(table):
    rows = [{"task": "RememberColor3-VLA-v0", "controller": "learned", "none": 0.32, "wrong": 0.0, "oracle": 0.94,
             "recall": 0.94, "greedy_retrieval": 1.0},
            {"task": "TakeItBack-VLA-v0", "controller": "learned", "none": 0.5, "wrong": 0.0, "oracle": 0.0,
             "recall": 0.0, "greedy_retrieval": 0.5}]
    text = table.markdown(rows)
    assert "| RememberColor3-VLA-v0 | learned | 32% | 0% | 94% | 94% | 100% | 1.00 |" in text
    assert "| TakeItBack-VLA-v0 | learned | 50% | 0% | 0% | 0% | 50% | - |" in text  # no ratio over a 0% oracle
    assert "| ELMUR | 89% | 19% | 23% |" in text
    assert text.splitlines()[-1] == "| sb3-memret (recall, this run) | 94% | - | - |"  # tasks not run show '-'


def test_a_folder_that_is_not_a_recall_run_is_refused_by_name(table, tmp_path):
    with pytest.raises(SystemExit, match=str(tmp_path)):
        table.run_setting(tmp_path)
