"""MIKASA-Robo-VLA's task table: which tasks a split holds, their memory types, and the seeds episodes play.

``mikasa_robo_vla_envs.csv`` beside this module is MIKASA-Robo-VLA's own manifest (the file of that name at the
top of the MIKASA-Robo repository, ``vla`` branch), in its format (semicolon-delimited; ``id;Name;Max Length;
Memory Type;Horizon Split;Data Source;language_instruction``). The ``mikasa-robo-suite`` 1.0.0 wheel does not ship
it (its ``benchmarking.default_task_csv_path()`` names a file that is not installed), so the project carries it.
It was rebuilt from the repository's published task catalogue (90 tasks, their horizons, data sources and
instructions) and its benchmarking page: the memory type of each family, and the split rule ``Max Length <= 200``
short, ``201..601`` medium, above that long. Rebuilt so, it reproduces the page's counts exactly: short 38
(Spatial 14, Object 9, Negative 9, Temporal 3, Tracking 2, Prospective 1), medium 30, long 22.

Tasks are selected by MIKASA's own ``select_benchmark_tasks`` reading this file.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Sequence

if TYPE_CHECKING:
    from mikasa_robo_suite.vla.benchmarking import BenchmarkTask

MANIFEST = Path(__file__).with_name("mikasa_robo_vla_envs.csv")
SPLITS = ("short", "medium", "long", "all")
# MIKASA-Robo-VLA's evaluation seeds (episode i plays 4242424242 + i) and the development seeds (5000 + i) for
# choices made before the protocol's figure: the tasks' own (MikasaCueTask.evaluation_seeds, development_seeds)
PROTOCOL_SEED, DEV_SEED = 4242424242, 5000
SEED_SETS = {"protocol": PROTOCOL_SEED, "dev": DEV_SEED}


def episode_seeds(seed_set: str, episodes: int) -> list[int]:
    """The env seeds of ``episodes`` episodes of ``seed_set`` ("protocol": the benchmark's test seeds, "dev")."""
    if seed_set not in SEED_SETS:
        raise ValueError(f"unknown seed set {seed_set!r}; expected one of {sorted(SEED_SETS)}")
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    return [SEED_SETS[seed_set] + i for i in range(episodes)]


def manifest_ids() -> set[str]:
    """Every env id of the manifest."""
    from mikasa_robo_suite.vla.benchmarking import select_benchmark_tasks

    return {task.env_id for task in select_benchmark_tasks(split="all", csv_path=MANIFEST)}


def select_tasks(split: str | None = None, env_ids: Sequence[str] | None = None) -> list["BenchmarkTask"]:
    """The manifest's tasks of ``split`` (short / medium / long / all), or exactly ``env_ids`` in their order, by
    MIKASA's ``select_benchmark_tasks``. An id not in the manifest is refused (MIKASA's would accept it as a
    "custom" task of unknown memory type, which a split's table cannot place)."""
    from mikasa_robo_suite.vla.benchmarking import select_benchmark_tasks

    if (split is None) == (env_ids is None):
        raise ValueError("name a split or a list of tasks, not both")
    if split is not None and split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {list(SPLITS)}")
    if env_ids is not None:
        known = manifest_ids()
        unknown = [env_id for env_id in env_ids if env_id not in known]
        if unknown:
            raise ValueError(f"{unknown} are not MIKASA-Robo-VLA benchmark tasks; the manifest ({MANIFEST.name}) "
                             f"lists {len(known)}, e.g. {sorted(known)[:4]}")
        return select_benchmark_tasks(env_ids=list(env_ids), csv_path=MANIFEST)
    return select_benchmark_tasks(split=split, csv_path=MANIFEST)


__all__ = ["DEV_SEED", "MANIFEST", "PROTOCOL_SEED", "SEED_SETS", "SPLITS", "episode_seeds", "manifest_ids", "select_tasks"]
