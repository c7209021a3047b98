"""Write the table of registered tasks (``docs/task_list.md``, included by ``docs/tasks.md``) from the registry.

Every name ``--task`` accepts, with the module that defines it, MIKASA-Robo-VLA's split, memory type and horizon for
it (from the benchmark's manifest), its replan interval, the controller a command runs on it by default (and
``scripted-camera`` where its expert has a version on the cameras alone), and whether it can run on this machine. To
fit the page's width the module is the link behind the task's name, MIKASA-Robo-VLA's three values share one column,
and "here" is a word: a registered task that cannot run here, or whose module does not load, is marked with a number
whose note, under the table, says why. Run by ``docs/conf.py``; ``python docs/generate_tasks.py OUT.md`` writes it
alone.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

def _manifest() -> dict[str, object]:
    from sb3_memret.benchmark.manifest import select_tasks

    return {row.env_id: row for row in select_tasks("all")}


def _linked(name: str, module: str) -> str:
    """The task's name as a link to the API page of the module that defines it."""
    return f"{{py:mod}}`{name} <{module}>`"


def render() -> str:
    from sb3_memret.tasks import check_task_name, make_task, task_names
    from sb3_memret.tasks.mikasa.camera_experts import has_camera_expert

    manifest = _manifest()
    notes: list[str] = []  # why a task cannot run here, each reason once, numbered in order of first use

    def note(reason: str) -> str:
        if reason not in notes:
            notes.append(reason)
        return f"\u00a0({notes.index(reason) + 1})"  # no-break space: "no (1)" stays on one line

    lines = ["| task | split, memory type, steps | replan | controller | here |",
             "|---|---|---|---|---|"]
    for name in task_names():
        row = manifest.get(name)  # one column: three narrow ones would not fit the page
        mikasa = f"{row.split}, {row.memory_type}, {row.max_episode_steps}" if row else ""
        try:
            check_task_name(name)
        except ValueError as err:  # a registered task that cannot run here is not made
            why = re.sub(r",? missing at [^\s;,]+", "", str(err).split(": ", 1)[-1]).rstrip(".")
            lines.append(f"| `{name}` | {mikasa} | | | no{note(f'{why}.')} |")
            continue
        try:
            task = make_task(name)
        except Exception as err:  # a broken task module: the table says so rather than hide the task
            lines.append(f"| `{name}` | {mikasa} | | | "
                         f"no{note(f'does not load: {type(err).__name__}: {err}')} |")
            continue
        also = " (also `scripted-camera`)" if has_camera_expert(task) else ""  # its expert on the cameras alone
        lines.append(f"| {_linked(name, type(task).__module__)} | {mikasa} | {task.replan_every} | "
                     f"`{task.default_controller}`{also} | yes |")
    text = "\n".join(lines) + "\n"
    if notes:
        text += "\n" + "".join(f"{k}. {' '.join(reason.split())}\n" for k, reason in enumerate(notes, 1))
    return text


def main(out: Path) -> Path:
    out = Path(out)
    text = render()
    if not out.is_file() or out.read_text() != text:  # unchanged: Sphinx need not read the page again
        out.write_text(text)
    return out


if __name__ == "__main__":
    print(main(Path(sys.argv[1])))
