"""Which wording of a FindImposter cue the scripted expert follows better: one fact naming the set ("set") or one
fact per object shown ("each").

For each task and wording, ``--episodes`` episodes at development seeds ``--seed`` + i under each condition:
``oracle`` (the true facts), and ``written`` (what the task's writer wrote from the base camera so far, every fact
in the prompt, no retriever), through ``evaluate_task_condition`` (the rollout's code). The expert stands in for a
controller finetuned on that wording; it reads both exactly, so what differs is what reaches it.

    .venv/bin/python lab/2026-11-27-imposter-wordings/imposter_wordings.py [--tasks FindImposterColor3-VLA-v0 ...] [--episodes 10]
"""

from __future__ import annotations

import argparse

TASKS = tuple(f"FindImposter{family}{size}-VLA-v0" for family, sizes in (
    ("Color", ("3", "5", "9")), ("Shape", ("3", "5", "9")), ("ShapeAndColor", ("3x2", "3x3", "5x3"))) for size in sizes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument("--conditions", nargs="+", default=["oracle", "written"])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=5000, help="first development seed (not MIKASA's 4242424242 + i)")
    args = parser.parse_args()

    from sb3_memret.evaluation.rollout import evaluate_task_condition
    from sb3_memret.tasks import make_task
    from sb3_memret.tasks.mikasa.find_imposter.task import WORDINGS

    for env_id in args.tasks:
        for wording in WORDINGS:
            task = type(make_task(env_id))(env_id, wording)
            line = []
            for condition in args.conditions:
                results = evaluate_task_condition(task.expert(), condition, task, args.episodes, seed=args.seed,
                                                  render_backend="cpu", protocol_seeds=False)
                line.append(f"{condition} {sum(r.success for r in results)}/{len(results)}")
            print(f"{env_id} {wording:4s} " + "  ".join(line), flush=True)


if __name__ == "__main__":
    main()
