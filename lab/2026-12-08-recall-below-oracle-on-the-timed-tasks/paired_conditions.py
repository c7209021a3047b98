"""The written condition's episodes beside a table's other conditions on the same tasks and seeds: per task each
condition's successes on the seeds both played, and written against each other condition paired by seed (the
discordant pairs and McNemar's exact two-sided p-value). Only the table's episodes of one controller are read.

Usage: paired_conditions.py TABLE/episodes.jsonl WRITTEN/episodes.jsonl CONTROLLER_SHA256_PREFIX
"""
import collections
import json
import sys
from math import comb


def mcnemar(b: int, c: int) -> float:
    """Exact two-sided p-value of b against c discordant pairs."""
    n = b + c
    return 1.0 if n == 0 else min(1.0, 2 * sum(comb(n, k) for k in range(min(b, c) + 1)) / 2 ** n)


def outcomes(path: str, prefix: str) -> dict[tuple[str, str, int], bool]:
    """The last recorded outcome of each (task, condition, seed) played by the controller ``prefix`` names."""
    kept = {}
    for line in open(path):
        e = json.loads(line)
        if "success" in e and e.get("controller_sha256", "").startswith(prefix):
            kept[e["env_id"], e["condition"], e["seed"]] = bool(e["success"])
    return kept


table, written = outcomes(sys.argv[1], sys.argv[3]), outcomes(sys.argv[2], sys.argv[3])
seeds = collections.defaultdict(set)
for task, _, seed in written:
    seeds[task].add(seed)
print("| task | seeds | none | oracle | wrong | recall | written | written vs oracle | written vs recall |")
print("|---|---|---|---|---|---|---|---|---|")
for task, played in seeds.items():
    cells, paired = [], []
    for condition in ("none", "oracle", "wrong", "recall"):
        both = [s for s in played if (task, condition, s) in table]
        cells.append(f"{sum(table[task, condition, s] for s in both)}/{len(both)}" if both else "")
        if condition in ("oracle", "recall"):
            only_written = sum(written[task, "written", s] and not table[task, condition, s] for s in both)
            only_other = sum(table[task, condition, s] and not written[task, "written", s] for s in both)
            paired.append(f"{only_written} vs {only_other}, p = {mcnemar(only_written, only_other):.3g}")
    print(f"| {task} | {len(played)} | {' | '.join(cells)} | {sum(written[task, 'written', s] for s in played)}/"
          f"{len(played)} | {' | '.join(paired)} |")
