"""Two benchmark runs' episodes paired by (task, condition, seed): each side's successes on the seeds both played,
the discordant pairs and McNemar's exact two-sided p-value.

Usage: paired.py BEFORE/episodes.jsonl AFTER/episodes.jsonl [CONDITION]
"""
import collections
import json
import sys
from math import comb


def outcomes(path: str, condition: str) -> dict[tuple[str, int], bool]:
    """The last recorded outcome of each (task, seed) under ``condition``."""
    kept = {}
    for line in open(path):
        e = json.loads(line)
        if e["condition"] == condition:
            kept[e["env_id"], e["seed"]] = bool(e["success"])
    return kept


def mcnemar(b: int, c: int) -> float:
    """Exact two-sided p-value of b against c discordant pairs."""
    n = b + c
    if n == 0:
        return 1.0
    return min(1.0, 2 * sum(comb(n, k) for k in range(min(b, c) + 1)) / 2 ** n)


before, after = (outcomes(p, sys.argv[3] if len(sys.argv) > 3 else "oracle") for p in sys.argv[1:3])
tasks = collections.defaultdict(list)
for key in sorted(before.keys() & after.keys()):
    tasks[key[0]].append((before[key], after[key]))
print("| task | seeds | before | after | only before | only after | p |\n|---|---|---|---|---|---|---|")
total = [0, 0, 0, 0, 0]
for task, pairs in tasks.items():
    b = sum(x and not y for x, y in pairs)
    c = sum(y and not x for x, y in pairs)
    row = [len(pairs), sum(x for x, _ in pairs), sum(y for _, y in pairs), b, c]
    total = [t + r for t, r in zip(total, row)]
    print(f"| {task} | " + " | ".join(map(str, row)) + f" | {mcnemar(b, c):.3g} |")
print(f"| all | " + " | ".join(map(str, total)) + f" | {mcnemar(total[3], total[4]):.3g} |")
