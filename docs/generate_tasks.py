"""Write the table of registered tasks (``docs/task_list.md``, included by ``docs/tasks.md``) from the registry.

Every name ``--task`` accepts, with the module that defines it, MIKASA-Robo-VLA's split, memory type and horizon for
it (from the benchmark's manifest), its replan interval, the controller a command runs on it by default, and whether
it can run on this machine (a registered task that cannot says why). Run by ``docs/conf.py``; ``python
docs/generate_tasks.py OUT.md`` writes it alone.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path


def _manifest() -> dict[str, object]:
    from sb3_memret.benchmark.manifest import select_tasks

    return {row.env_id: row for row in select_tasks("all")}


def render() -> str:
    from sb3_memret.tasks import check_task_name, make_task, task_names

    manifest = _manifest()
    lines = ["| task | defined in | split | memory type | steps | replan | default controller | here |",
             "|---|---|---|---|---|---|---|---|"]
    for name in task_names():
        row = manifest.get(name)
        split, memory_type, steps = (row.split, row.memory_type, row.max_episode_steps) if row else ("", "", "")
        try:
            check_task_name(name)
        except ValueError as err:  # a registered task that cannot run here is not made
            why = re.sub(r",? missing at \S+", "", str(err).split(": ", 1)[-1].split(";")[0]).replace("|", "/")
            lines.append(f"| `{name}` | | {split} | {memory_type} | {steps} | | | not here: {why} |")
            continue
        try:
            task = make_task(name)
        except Exception as err:  # a broken task module: the table says so rather than hide the task
            lines.append(f"| `{name}` | | {split} | {memory_type} | {steps} | | | does not load: "
                         f"{type(err).__name__}: {str(err).replace('|', '/')} |")
            continue
        lines.append(f"| `{name}` | {{py:mod}}`{type(task).__module__}` | {split} | {memory_type} | {steps} | "
                     f"{task.replan_every} | `{task.default_controller}` | runs |")
    return "\n".join(lines) + "\n"


def main(out: Path) -> Path:
    out = Path(out)
    text = render()
    if not out.is_file() or out.read_text() != text:  # unchanged: Sphinx need not read the page again
        out.write_text(text)
    return out


if __name__ == "__main__":
    print(main(Path(sys.argv[1])))
