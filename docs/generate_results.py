"""Write the documentation's results pages (``docs/results/``) from the result files committed under ``benchmarks/``.

Every ``benchmarks/**/results.json`` (what ``sb3-memret benchmark mikasa`` writes into its run folder) becomes one
page: its tables come from the benchmark's own renderer (``sb3_memret.benchmark.report.render_report``), its figure
from ``plot_success``, each table names the file it came from, and the page gives the command that produces (and
resumes) the run, rebuilt from the run's recorded protocol. The run folder's episode log (``episodes.jsonl``) adds a
table of what was played. So does every seed sweep, a folder whose subfolders are training runs (what ``sb3-memret
train`` writes): its table and figure come from the runs' files, beside the folder's ``about.md``, the one text
written by hand (what the controller reads, on which seeds the settings were chosen). So does every learners folder
(what ``sb3-memret benchmark learners`` writes): a row a task's learner from its run's files. No figure is typed by
hand: a figure changes only with the files.

Run by ``docs/conf.py`` before Sphinx reads the pages; ``python docs/generate_results.py`` writes them alone.
"""

from __future__ import annotations

import json
import shlex
from collections import defaultdict
from pathlib import Path
from typing import Any, Mapping

RESULTS_FILE, EPISODES_FILE, PROTOCOL_FILE = "results.json", "episodes.jsonl", "protocol.json"
SWEEP_ABOUT = "about.md"  # a seed sweep's own words: what its controller reads, where its settings were chosen
BENCHMARKS = "benchmarks"


def _write(path: Path, text: str) -> None:
    """Write ``text`` unless ``path`` holds it already (an unchanged page keeps its time stamp: Sphinx skips it)."""
    if not path.is_file() or path.read_text() != text:
        path.write_text(text)


def slug(run: Path) -> str:
    """The page name of a run folder relative to ``benchmarks/`` (``mikasa/short-scripted-protocol`` ->
    ``mikasa-short-scripted-protocol``)."""
    return "-".join(run.parts)


def split_of(tasks: Mapping[str, Any]) -> str | None:
    """The split whose every task the run holds, exactly; None when the run names its tasks (``--tasks``)."""
    from sb3_memret.benchmark.manifest import select_tasks

    splits = {t.get("split") for t in tasks.values()}
    if len(splits) != 1:
        return None
    split = splits.pop()
    return split if [row.env_id for row in select_tasks(split)] == list(tasks) else None


def command(content: Mapping[str, Any], folder: str) -> str:
    """The ``sb3-memret benchmark mikasa`` command line that plays (or resumes) this run into ``folder``."""
    from sb3_memret.benchmark.learners import SHIPPED_LEARNER
    from sb3_memret.benchmark.learners import stored_learners

    protocol, tasks = content["protocol"], content["tasks"]
    split = split_of(tasks)
    args = ["sb3-memret", "benchmark", "mikasa"]
    args += ["--split", split] if split else ["--tasks", ",".join(tasks)]
    args += ["--controller", protocol["controller"], "--conditions", ",".join(protocol["conditions"]),
             "--seeds", protocol["seed_set"], "--episodes", str(protocol["episodes"])]
    if protocol.get("replan_every") is not None:
        args += ["--replan-every", str(protocol["replan_every"])]
    for source in stored_learners(protocol.get("learners")):  # the package's learner by its name, not its path
        args += ["--learners", "shipped" if source.name == SHIPPED_LEARNER.name and source.parent.name ==
                 SHIPPED_LEARNER.parent.name else str(source)]
    args += ["--out", folder]
    return " ".join(shlex.quote(a) for a in args)


def episode_table(log: Path, source: str) -> list[str]:
    """What the episode log holds, per task and condition: episodes, successes, mean return and steps, and how
    many versions of the task's code and of its controller played them (a digest each)."""
    cells: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for line in log.read_text().splitlines():
        if line.strip():
            record = json.loads(line)
            cells[record["env_id"], record["condition"]].append(record)
    if not cells:
        return []
    lines = ["## Episode log", "",
             "Every episode the run played, as its log records it (a resumed run only adds to it; an episode whose "
             "task or controller code has changed since is played again, so a cell may hold more than one version).",
             "", "| task | condition | episodes logged | successes | mean return | mean steps | task code versions | "
             "controller versions |", "|---|---|---|---|---|---|---|---|"]
    for (env_id, condition), records in cells.items():
        played = [r for r in records if "error" not in r]
        errors = len(records) - len(played)
        wins = sum(bool(r["success"]) for r in played)
        mean_return = sum(r["return"] for r in played) / len(played) if played else float("nan")
        mean_steps = sum(r["steps"] for r in played) / len(played) if played else float("nan")
        logged = f"{len(played)}" + (f" (+{errors} errors)" if errors else "")
        lines.append(f"| {env_id} | {condition} | {logged} | {wins} | {mean_return:.2f} | {mean_steps:.1f} | "
                     f"{len({r.get('task_sha256') for r in played})} | "
                     f"{len({r.get('controller_sha256') for r in played})} |")
    lines += ["", f"Source: `{source}`.", ""]
    return lines


def _with_sources(report: str, source: str, figure: str) -> list[str]:
    """``render_report``'s markdown with a source line after each table and the figure pointed at ``figure``."""
    from sb3_memret.benchmark.report import FIGURE_FILE

    out: list[str] = []
    lines = report.splitlines()
    for i, line in enumerate(lines):
        out.append(line.replace(f"]({FIGURE_FILE})", f"]({figure})"))
        ends_table = line.startswith("|") and (i + 1 == len(lines) or not lines[i + 1].startswith("|"))
        if ends_table:
            out += ["", f"Source: `{source}`."]
    return out


def run_page(root: Path, results: Path, out: Path) -> tuple[str, dict[str, Any]]:
    """Write the page (and figure) of one run folder's ``results.json`` into ``out``; its page name and content."""
    from sb3_memret.benchmark.report import plot_success, render_report

    content = json.loads(results.read_text())
    run = results.parent.relative_to(root)
    name = slug(run.relative_to(BENCHMARKS))
    figure = f"{name}.png"
    plot_success(content, out / figure)
    source = f"{run.as_posix()}/{RESULTS_FILE}"
    report = _with_sources(render_report(content), source, figure)
    title, body = report[0], report[1:]
    files = sorted(p.name for p in results.parent.iterdir() if p.is_file())
    lines = [title, "",
             f"Generated from `{source}` when the documentation was built; the tables and the figure are that "
             "file's, drawn by the benchmark's own report renderer. The run was made, and resumes, with:", "",
             "```bash", command(content, run.as_posix()), "```", "",
             f"`sb3-memret benchmark report {run.as_posix()}` makes `results.json` and `report.md` again from the "
             "run's episode log.", *body]
    log = results.parent / EPISODES_FILE
    if log.is_file():
        lines += episode_table(log, f"{run.as_posix()}/{EPISODES_FILE}")
    lines += ["## Files", "", f"The run folder `{run.as_posix()}/` holds: " + ", ".join(f"`{f}`" for f in files) +
              f" (`{PROTOCOL_FILE}`: the settings the run was started with; `report.md` and `success.png`: the "
              "benchmark's own rendering of the same results).", ""]
    _write(out / f"{name}.md", "\n".join(lines))
    return name, content


def sweeps(root: Path) -> list[Path]:
    """The seed sweeps under ``root/benchmarks``: folders whose subfolders are finished training runs, learners
    folders (``learners_folders``) aside."""
    from sb3_memret.analysis.learners import is_learners_folder
    from sb3_memret.analysis.sweep import is_run

    folders = {run.parent.parent for run in (root / BENCHMARKS).glob("**/evaluations.jsonl") if is_run(run.parent)}
    return sorted(folder for folder in folders if not is_learners_folder(folder))


def learners_folders(root: Path) -> list[Path]:
    """The learners folders under ``root/benchmarks`` (``sb3-memret benchmark learners --out``)."""
    from sb3_memret.analysis.learners import LEARNERS_FILE

    return sorted(index.parent for index in (root / BENCHMARKS).glob(f"**/{LEARNERS_FILE}"))


def learners_page(root: Path, folder: Path, out: Path) -> tuple[str, list[dict[str, Any]]]:
    """Write the page of one learners folder into ``out``; its page name and its rows (``learner_rows``)."""
    from sb3_memret.analysis.learners import LEARNERS_FILE, learner_rows, learners_table

    rows = learner_rows(folder)
    where = folder.relative_to(root).as_posix()
    name = slug(folder.relative_to(root / BENCHMARKS))
    trained = [row for row in rows if row["state"] == "trained"]
    summaries = [row["summary"] for row in trained]
    controllers = sorted({summary.get("controller", "?") for summary in summaries})
    settings = ""  # the command's own settings, as the first trained run recorded them
    if summaries:
        first = summaries[0]
        settings = (f" --controller {first['controller']} --seed {first['seed']} --eval-episodes {first['eval_episodes']}"
                    + (f" --stop-at-greedy {first['stop_at_greedy']} --stop-patience {first['stop_patience']}"
                       if first.get("stop_at_greedy") is not None else ""))
    tasks = ",".join(row["task"] for row in rows)
    lines = [f"# Memory learners: {folder.name}", "",
             f"Generated from the training runs committed under `{where}/` when the documentation was built: each "
             f"task's row is its run folder's `summary.json` and `evaluations.jsonl`, the tasks its `{LEARNERS_FILE}` "
             f"lists. One `train recall` run a task on its zoo section, serving the frozen controller "
             f"{', '.join(f'`{c}`' for c in controllers) or '(none trained yet)'}; held-out evaluations play "
             "development seeds, never the benchmark's protocol seeds. The tables' recall cells play these learners "
             "(`benchmark mikasa --learners`).", "",
             "```bash", f"sb3-memret benchmark learners --tasks {tasks}{settings} --out {where}", "```", "",
             *learners_table(rows), "", f"Source: `{where}/*/evaluations.jsonl`, `{where}/*/summary.json`.", ""]
    _write(out / f"{name}.md", "\n".join(lines))
    return name, rows


def sweep_page(root: Path, folder: Path, out: Path) -> tuple[str, list[dict[str, Any]]]:
    """Write the page (and figure) of one seed sweep into ``out``; its page name and its rows."""
    from sb3_memret.analysis.sweep import is_run, plot_sweep, run_row, sweep_table

    pairs = sorted(((run_row(run), run) for run in folder.iterdir() if is_run(run)), key=lambda pair: pair[0]["seed"])
    rows, runs = [row for row, _ in pairs], [run for _, run in pairs]
    about = folder / SWEEP_ABOUT
    if not about.is_file():
        raise FileNotFoundError(f"{about} is missing: a seed sweep states what its controller reads and on which seeds "
                                "its settings were chosen")
    where = folder.relative_to(root).as_posix()
    name = slug(folder.relative_to(root / BENCHMARKS))
    figure = f"{name}.png"
    plot_sweep(runs, out / figure)
    first = json.loads((runs[0] / "summary.json").read_text())
    config = f"{where}/{runs[0].name}/config.yml"
    lines = [f"# Seed sweep: {folder.name}", "",
             f"Generated from the training runs committed under `{where}/` when the documentation was built: each "
             f"row is one run folder's `summary.json` and `evaluations.jsonl`. The runs differ only in their training "
             f"seed; each was made with the frozen controller `{first.get('controller', '?')}` and the hyperparameters "
             f"in its `config.yml`, held-out evaluations at seed {first.get('eval_seed')} (never trained on):", "",
             "```bash", f"sb3-memret train recall --report --seed SEED --config {config} --out {where}/seedSEED",
             "```", "", about.read_text().strip(), "", *sweep_table(rows), "",
             f"Source: `{where}/*/evaluations.jsonl`, `{where}/*/summary.json`.", ""]
    if any(row["oracle"] == row["oracle"] for row in rows):  # some report played the baselines (not NaN)
        lines += ["The oracle (the true fact in the prompt) and no-memory (the bare instruction) columns are each "
                  "run's report's, played on the same held-out episodes as its final evaluation.", ""]
    lines += [f"![held-out greedy accuracy, sampled fraction and entropy of every run]({figure})", "",
              "*Held-out greedy accuracy (solid), sampled fraction (dotted) and policy entropy of each run, by "
              "round.*", "", "## Files", "",
              f"Each run folder under `{where}/` holds: " + ", ".join(
                  f"`{f}`" for f in sorted({p.name for run in runs for p in run.iterdir() if p.is_file()})) + ".", ""]
    _write(out / f"{name}.md", "\n".join(lines))
    return name, rows


def _progress(content: Mapping[str, Any]) -> str:
    cells = [cell for t in content["tasks"].values() for cell in t.get("conditions", {}).values()]
    complete = sum(bool(cell.get("complete")) for cell in cells)
    return f"{complete} of {len(cells)}"


def main(root: Path, out: Path) -> list[Path]:
    """Write ``out/index.md`` and a page per committed benchmark run under ``root/benchmarks``; the pages."""
    root, out = Path(root), Path(out)
    out.mkdir(parents=True, exist_ok=True)
    runs = sorted((root / BENCHMARKS).glob(f"**/{RESULTS_FILE}"))
    pages = [run_page(root, results, out) for results in runs]
    sweep_pages = [sweep_page(root, folder, out) for folder in sweeps(root)]
    learner_pages = [learners_page(root, folder, out) for folder in learners_folders(root)]
    lines = ["# Results", "",
             "One page per benchmark run committed under `benchmarks/`, generated from its `results.json` when the "
             "documentation is built (`docs/generate_results.py`). A run in progress shows the cells it has "
             "completed; the protocol is on [the benchmark page](../benchmark.md). Studies made during development (pilots, "
             "probes, figures measured by hand) are kept apart from the product, in the repository's `lab/` folder: "
             "a dated folder per study, with its command and its result files.", ""]
    if pages:
        lines += ["| run | benchmark | controller | seeds | conditions | tasks | cells complete |",
                  "|---|---|---|---|---|---|---|"]
        for name, content in pages:
            p = content["protocol"]
            from sb3_memret.benchmark.report import privileged_upper_bound

            bound = " (a privileged upper bound: it reads the simulator)" if privileged_upper_bound(content) else ""
            lines.append(f"| [{name}]({name}.md) | {p['benchmark']} | `{p['controller']}`{bound} | {p['seed_set']} "
                         f"({p['episodes']} a cell) | {', '.join(p['conditions'])} | {len(content['tasks'])} | "
                         f"{_progress(content)} |")
    else:
        lines += ["No benchmark run is committed yet.", ""]
    if sweep_pages:
        lines += ["", "Seed sweeps of training runs:", "", "| sweep | runs | seeds | mastered and held from the middle "
                  "on |", "|---|---|---|---|"]
        for name, rows in sweep_pages:
            lines.append(f"| [{name}]({name}.md) | {len(rows)} | {', '.join(str(r['seed']) for r in rows)} | "
                         f"{sum(r['held_from_middle'] for r in rows)} of {len(rows)} |")
    if learner_pages:
        lines += ["", "Memory learners of the recall condition (`sb3-memret benchmark learners`):", "",
                  "| learners | tasks | trained |", "|---|---|---|"]
        for name, rows in learner_pages:
            lines.append(f"| [{name}]({name}.md) | {len(rows)} | "
                         f"{sum(row['state'] == 'trained' for row in rows)} |")
    names = [name for name, _ in pages] + [name for name, _ in sweep_pages] + [name for name, _ in learner_pages]
    if names:
        lines += ["", "```{toctree}", ":hidden:", "", *names, "```", ""]
    _write(out / "index.md", "\n".join(lines))
    keep = {"index.md", *(f"{name}.md" for name in names), *(f"{name}.png" for name in names)}
    for stale in out.iterdir():
        if stale.name not in keep:
            stale.unlink()
    return [out / "index.md", *(out / f"{name}.md" for name in names)]


if __name__ == "__main__":
    docs = Path(__file__).resolve().parent
    for page in main(docs.parent, docs / "results"):
        print(page)
