"""The seed ranges that keep episodes apart: training rollouts start at 0, demonstrations at ``DEMO_SEED`` and
held-out evaluations at ``HELD_OUT_SEED``, so no evaluated placement was trained on or demonstrated. (A benchmark's
own test seeds, such as MIKASA's, live with its manifest: ``sb3_memret.benchmark.manifest``.)"""

DEMO_SEED = 100_000
HELD_OUT_SEED = 1_000_000
# a task's own held-out seed sets (Task.evaluation_seeds, Task.development_seeds): its benchmark's test set, for the
# final figure only, and the seeds every choice is made on (the default everywhere)
HELD_OUT_KINDS = ("evaluation", "development")


def held_out_seeds(task, kind: str, n: int) -> list[int] | None:
    """The first ``n`` of ``task``'s ``kind`` seeds (``Task.evaluation_seeds``, ``Task.development_seeds``), or None
    where it has none; an unknown kind is refused."""
    if kind not in HELD_OUT_KINDS:
        raise ValueError(f"unknown held-out seed kind {kind!r}; expected one of {list(HELD_OUT_KINDS)}")
    return getattr(task, f"{kind}_seeds")(n)

__all__ = ["DEMO_SEED", "HELD_OUT_KINDS", "HELD_OUT_SEED", "held_out_seeds"]
