"""One markdown report of a training run: what was learned, the curves, the tables, the trace, the config.

It reads what the run folder already holds (``summary.json``, ``evaluations.jsonl``,
``progress.csv``, ``config.yml``, the initial and final models, any ``ablations/*.md`` written
by ``sb3-memret ablate --out RUN/ablations``) and adds what only a fresh evaluation can say:
the oracle and no-memory baselines on the same held-out episodes as the final evaluation,
and the before/after introspection trace. The baselines and the report's time go into the run's ``summary.json``
beside training's, so a seed sweep's page can show them without playing anything again.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from stable_baselines3.common.vec_env import VecEnv

from sb3_memret.common.seeds import HELD_OUT_SEED
from sb3_memret.tasks import make_task, task_in
from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.evaluation.retrieval import RetrievalReport, evaluate_retrieval
from sb3_memret.analysis.plotting import PLOT_FILE, plot_learning_curves
from sb3_memret.analysis.sweep import MASTERY, first_mastered
from sb3_memret.policy.ppo import MemRetPPO, load_model
from sb3_memret.analysis.trace import model_label, trace_models
from sb3_memret.training.run import (CONFIG_FILE, INITIAL_MODEL, eval_env_kwargs, format_history, load_run_config,
                                 read_history, retrieval_chance)

REPORT_FILE = "report.md"
CONDITION_PROMPTS = {
    "recall": "the instruction + the memory the retriever picks",
    "oracle": "the instruction + the true memory",
    "none": "the bare instruction",
}


@dataclass
class ReportOptions:
    """How to fill the parts of a report that need fresh evaluation."""

    controller: str = "scripted"
    baseline_episodes: int | None = None  # None: as many as the final evaluation; 0: skip the baselines
    n_envs: int = 2
    trace_seed: int | None = None  # None: the run's held-out evaluation seed
    render_backend: str | None = None  # None: the run's task's default
    backend: str = "auto"  # where the baselines' physics runs (sb3_memret.physics.BACKENDS)
    ray_address: str | None = None


def write_report(run: Path, options: ReportOptions | None = None,
                 on_progress: Callable[[str], None] | None = None, venv: VecEnv | None = None) -> Path:
    """Write ``run/report.md`` (and ``run/learning_curves.png``) and return the report's path. ``venv``: the
    run's own held-out envs, still open, to play the baselines on (else new ones are started and closed)."""
    run, options = Path(run), options or ReportOptions()
    say = on_progress or (lambda _: None)
    summary_path = run / "summary.json"
    if not summary_path.exists():
        raise FileNotFoundError(f"{str(run)!r} has no summary.json: not a finished training run "
                                f"(sb3-memret train writes it when training ends)")
    summary = json.loads(summary_path.read_text())
    task = task_in(load_run_config(run).env_kwargs if (run / CONFIG_FILE).exists() else {})
    summary.setdefault("task", task)
    history = read_history(run)
    if not history:
        raise ValueError(f"{str(run)!r} holds no evaluations (evaluations.jsonl is missing or empty)")
    final_path = run / "final_model.zip"
    if not final_path.exists():
        raise FileNotFoundError(f"{str(run)!r} has no final_model.zip (an interrupted run: resume it to finish)")
    seconds: dict[str, float] = {}  # where the report's time goes, kept in summary.json
    clock = time.perf_counter()
    say("plotting learning curves")
    chance = retrieval_chance(run)
    plot_learning_curves(run, run / PLOT_FILE, chance=chance)
    seconds["plot"] = time.perf_counter() - clock
    eval_seed = summary.get("eval_seed", HELD_OUT_SEED)
    final = RetrievalReport.from_dict(summary["final_eval"]) if summary.get("final_eval") else None
    model = load_model(final_path)
    baselines = _baselines(model, final_path, final, eval_seed, options, say, venv, seconds)
    clock = time.perf_counter()
    say("tracing the first decision")
    traces = _traces(run, model, final_path, options, options.trace_seed if options.trace_seed is not None else eval_seed)
    seconds["trace"] = time.perf_counter() - clock
    sections = [
        f"# Training report: {run.name}",
        _overview(summary, history, chance, final, baselines),
        f"![learning curves]({PLOT_FILE})",
        "*At each held-out evaluation (markers): greedy retrieval accuracy, the sampled fraction (the chance a "
        "training-time draw holds the true memory), task success and the policy entropy (right axis); every round "
        "(thin lines): the share of that round's training draws that held it, and the training entropy.*",
        "## Held-out evaluations during training",
        f"{_episodes_per_evaluation(history)}, evaluation seed {eval_seed} (and the task's protocol "
        "seeds where it has them); "
        "greedy accuracy counts decisions where the acted memory was the true one, sampled is the chance "
        "a training-time draw holds it.",
        format_history(history),
        "## Final policy against the baselines",
        _baseline_table(final, baselines),
        "## Introspection trace",
        *_trace_section(traces),
        "## Controller ablations",
        _ablations(run, task),
        "## Configuration",
        f"`{run / CONFIG_FILE}`:",
        "```yaml\n" + (run / CONFIG_FILE).read_text().rstrip() + "\n```",
        f"Frozen controller: `{summary.get('controller', options.controller)}`"
        + (f"; training seed {summary['seed']}" if "seed" in summary else "")
        + f"; {summary['num_timesteps']} decisions in {summary['rounds']} rounds.",
        "## Reproduce",
        "```bash\n" + "\n".join([
            f"sb3-memret train recall --task {task} --seed {summary.get('seed', 0)} --out {run}",
            f"sb3-memret plot {run}",
            f"sb3-memret trace {run if (run / INITIAL_MODEL).exists() else final_path}",
            f"sb3-memret eval {final_path} --condition recall --episodes {history[-1]['episodes']}",
            f"sb3-memret ablate memcount --out {run / 'ablations'}",
            f"sb3-memret report {run}",
        ]) + "\n```",
    ]
    path = run / REPORT_FILE
    path.write_text("\n\n".join(sections) + "\n")
    summary = json.loads(summary_path.read_text())  # as training wrote it, with the report's time beside training's
    summary.setdefault("seconds", {})["report"] = seconds
    summary["baselines"] = {name: report.to_dict() for name, report in baselines.items()}
    summary_path.write_text(json.dumps(summary, indent=2))
    return path


def _episodes_per_evaluation(history: list[dict[str, Any]]) -> str:
    """'N episodes per evaluation', naming round 0's and the final one's counts where the config set them apart
    (initial_eval_episodes, final_eval_episodes)."""
    first, last = history[0], history[-1]
    middle = [row["episodes"] for row in history[1:-1]] or [last["episodes"]]
    usual = max(set(middle), key=middle.count)
    apart = []
    if first["round"] == 0 and first["episodes"] != usual:
        apart.append(f"{first['episodes']} at round 0, the untrained learner's")
    if len(history) > 1 and last["episodes"] != usual:
        apart.append(f"{last['episodes']} at round {last['round']}, the final one")
    return f"{usual} episodes per evaluation" + (f" ({'; '.join(apart)})" if apart else "")


def _overview(summary: dict[str, Any], history: list[dict[str, Any]], chance: float | None,
              final: RetrievalReport | None, baselines: dict[str, RetrievalReport]) -> str:
    first, last = history[0], history[-1]
    mastered = first_mastered(history)
    chance_text = f" (a random pick: {chance:.0%})" if chance is not None else ""
    lines = [
        f"PPO trained the retriever (actor) and the retention scorer (critic) from random initialisation for "
        f"{summary['rounds']} rounds ({summary['num_timesteps']} decisions, {summary['wall_seconds'] / 60:.1f} min). "
        f"What the frozen controller must know on task `{summary.get('task', 'drawer')}` (the drawer holding the "
        "cube, the cue's colour) reaches it only through the memory the retriever appends to its prompt; the "
        "reward is physics only, and no label says which memory is right.",
        "",
        "**What was learned**",
        "",
        f"- Greedy retrieval of the true memory on held-out episodes: {first['greedy_accuracy']:.0%} at "
        f"round {first['round']}{chance_text} → {last['greedy_accuracy']:.0%} at round {last['round']}.",
        f"- Greedy accuracy first reached {MASTERY:.0%} at round {mastered['round']} "
        f"({mastered['timesteps']} decisions)." if mastered else
        f"- Greedy accuracy never reached {MASTERY:.0%}; the best was {max(r['greedy_accuracy'] for r in history):.1%}.",
        f"- A training-time (sampled) retrieval holds the true memory {first['sampled_fraction']:.0%} → "
        f"{last['sampled_fraction']:.0%} of the time; policy entropy {first['entropy']:.2f} → {last['entropy']:.2f} nats.",
        f"- Task success: {first['success']['overall']:.0%} → {last['success']['overall']:.0%}.",
    ]
    if final is not None and baselines:
        parts = ", ".join(f"{name} {report.success['overall']:.0%} ({report.episodes})" for name, report in baselines.items())
        lines.append(f"- Final held-out success (episodes, from the same placement seeds): recall "
                     f"{final.success['overall']:.0%} ({final.episodes}); baselines {parts}.")
    return "\n".join(lines)


def _baselines(model: MemRetPPO, model_path: Path, final: RetrievalReport | None, eval_seed: int,
               options: ReportOptions, say: Callable[[str], None], venv: VecEnv | None,
               seconds: dict[str, float]) -> dict[str, RetrievalReport]:
    """The oracle and no-memory conditions on the final evaluation's episodes, one after the other on one
    set of physics workers (``RecallVecEnv.set_mode``): ``venv``'s, else new ones; ``seconds`` gets each one's time
    (and the workers' start, if new ones were started)."""
    episodes = options.baseline_episodes if options.baseline_episodes is not None else (final.episodes if final else 0)
    if episodes == 0:
        return {}
    own = venv is None
    if own:
        clock = time.perf_counter()
        venv = make_recall_vec_env(options.n_envs, eval_env_kwargs(model, model_path, "oracle", options.controller,
                                                                   options.render_backend),
                                   backend=options.backend, ray_address=options.ray_address)
        seconds["baseline_workers"] = time.perf_counter() - clock
    reports = {}
    try:
        for condition in ("oracle", "none"):
            clock = time.perf_counter()
            say(f"evaluating the {condition} baseline ({episodes} episodes)")
            venv.env_method("set_mode", condition)
            reports[condition] = evaluate_retrieval(model, venv, episodes, seed=eval_seed)
            seconds[condition] = time.perf_counter() - clock
    finally:
        if own:
            venv.close()
    return reports


def _baseline_table(final: RetrievalReport | None, baselines: dict[str, RetrievalReport]) -> str:
    rows = ([("recall", final)] if final else []) + list(baselines.items())
    if not rows:
        return "No final evaluation was recorded."
    groups = sorted({key for _, report in rows for key in report.success if key != "overall"})
    lines = ["| condition | prompt | episodes | greedy acc. | success | " + " | ".join(groups) + " |",
             "|---|---|---|---|---|" + "---|" * len(groups)]
    for name, report in rows:
        layers = " | ".join(f"{report.success[g]:.0%}" if g in report.success else "–" for g in groups)
        accuracy = f"{report.greedy_accuracy:.0%}" if name == "recall" else "–"
        lines.append(f"| {name} | {CONDITION_PROMPTS[name]} | {report.episodes} | {accuracy} | "
                     f"{report.success['overall']:.0%} | {layers} |")
    return "\n".join(lines)


def _traces(run: Path, model: MemRetPPO, final_path: Path, options: ReportOptions, seed: int) -> list:
    models = [(model_label(model, final_path), model)]
    if (run / INITIAL_MODEL).exists():
        initial = load_model(run / INITIAL_MODEL)
        models.insert(0, (model_label(initial, run / INITIAL_MODEL), initial))
    kwargs = eval_env_kwargs(model, final_path, "recall", options.controller, options.render_backend)
    return trace_models(models, kwargs, seed)


def _trace_section(traces: list) -> list[str]:
    head = (f'Instruction "{traces[0].instruction}". '
            f"Every memory in the bank at the first decision of held-out episode {traces[0].seed} (group "
            f"{traces[0].group}), with the retriever's score and first-pick probability; `*` marks a sampled "
            "pick, `C` the true memory.")
    note = "" if len(traces) > 1 else "\n\n(The run has no initial_model.zip, so only the final policy is traced.)"
    return [head + note, "```text\n" + "\n\n".join(t.format() for t in traces) + "\n```"]


def _ablations(run: Path, task: str) -> str:
    order = list(make_task(task).ablations())  # the task's order (the drawer's: the seed paper's)
    tables = [run / "ablations" / f"{name}.md" for name in order if (run / "ablations" / f"{name}.md").exists()]
    if not order:
        return f"Task {task!r} defines no controller ablation tables (`Task.ablations`)."
    if not tables:
        return (f"None saved with this run. `sb3-memret ablate {'|'.join(order)} --out {run / 'ablations'}` "
                "measures how the frozen controller consumes memory, and the next report includes the tables.")
    return "\n\n".join(path.read_text().strip() for path in tables)


__all__ = ["MASTERY", "ReportOptions", "first_mastered", "write_report"]
