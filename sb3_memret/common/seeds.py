"""The seed ranges that keep episodes apart: training rollouts start at 0, demonstrations at ``DEMO_SEED`` and
held-out evaluations at ``HELD_OUT_SEED``, so no evaluated placement was trained on or demonstrated. (A benchmark's
own test seeds, such as MIKASA's, live with its manifest: ``sb3_memret.benchmark.manifest``.)"""

DEMO_SEED = 100_000
HELD_OUT_SEED = 1_000_000
# a task's own held-out seed sets (Task.evaluation_seeds, Task.development_seeds): its benchmark's test set, for the
# final figure only, and the seeds every choice is made on (the default everywhere)
HELD_OUT_KINDS = ("evaluation", "development")

__all__ = ["DEMO_SEED", "HELD_OUT_KINDS", "HELD_OUT_SEED"]
