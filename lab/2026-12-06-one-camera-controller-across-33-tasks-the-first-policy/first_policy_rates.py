"""What a policy that played a recording did, read from the recording alone: per task, the episodes it won by the
kind of prompt it was told, and on Rotate how far the peg turned against the rotation asked.

The DAgger round of ``make controller-multitask`` is played by the first policy, the expert labelling, so its chunks
(``scripts/record_task_demos.sh``) are that policy's episodes at training-range seeds (neither development nor
protocol). Only finished chunks (``chunkN.done``) are read.

    .venv/bin/python lab/2026-12-06-one-camera-controller-across-33-tasks-the-first-policy/first_policy_rates.py \
        runs/stage1-multitask/dagger
"""

from __future__ import annotations

import argparse
import json
import re
from collections import defaultdict
from pathlib import Path

import numpy as np
import pandas as pd


def finished_chunks(root: Path) -> dict[str, list[Path]]:
    """Each task's finished chunks under ``root`` (``root/TASK/chunkN`` beside ``chunkN.done``)."""
    chunks: dict[str, list[Path]] = defaultdict(list)
    for done in sorted(root.glob("*/chunk*.done")):
        chunks[done.parent.name].append(done.with_suffix(""))
    return chunks


def episodes(chunk: Path) -> list[dict]:
    return [json.loads(line) for line in (chunk / "sb3_memret_episodes.jsonl").read_text().splitlines()]


def rates(chunks: dict[str, list[Path]]) -> list[tuple[str, dict[str, tuple[int, int]]]]:
    """Per task, won / played by prompt kind (matching: told the true fact; bare; mismatched), lowest matching rate
    first."""
    rows = []
    for task, paths in chunks.items():
        counts: dict[str, list[int]] = defaultdict(lambda: [0, 0])
        for chunk in paths:
            for episode in episodes(chunk):
                count = counts[episode["prompt_kind"]]
                count[0] += bool(episode["success"])
                count[1] += 1
        rows.append((task, {kind: (won, n) for kind, (won, n) in counts.items()}))
    return sorted(rows, key=lambda row: row[1].get("matching", (0, 1))[0] / max(row[1].get("matching", (0, 1))[1], 1))


def peg_turns(chunk: Path) -> list[tuple[int, float, float, bool]]:
    """On a Rotate chunk, each matching episode's (rotation asked, turn at the end, largest turn either way, won):
    the turn read from the layout's ``peg_yaw`` (the simulator's, recorded for the perception head's labels)."""
    info = json.loads((chunk / "meta" / "info.json").read_text())
    yaw_at = info["features"]["observation.state"]["names"].index("peg_yaw")
    frames = pd.concat(pd.read_parquet(f, columns=["observation.state", "episode_index", "task_index"])
                       for f in sorted((chunk / "data").glob("*/*.parquet")))
    prompts = pd.read_parquet(chunk / "meta" / "tasks.parquet")
    prompt_of = {int(i): text for text, i in zip(prompts.index, prompts["task_index"])}
    out = []
    for index, episode in enumerate(episodes(chunk)):
        if episode["prompt_kind"] != "matching":
            continue
        rows = frames[frames.episode_index == index]
        yaw = np.degrees(np.unwrap(np.stack(rows["observation.state"].values)[:, yaw_at].astype(float)))
        turned = yaw - yaw[0]
        asked = int(re.search(r"by (-?\d+) degrees", prompt_of[int(rows["task_index"].values[0])]).group(1))
        out.append((asked, float(turned[-1]), float(turned[np.abs(turned).argmax()]), bool(episode["success"])))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="a recording's root, e.g. runs/stage1-multitask/dagger")
    args = parser.parse_args()
    chunks = finished_chunks(args.root)
    print(f"| task | chunks | told the true fact | no fact | a wrong fact |\n|---|---|---|---|---|")
    for task, counts in rates(chunks):
        cells = [f"{counts[k][0]}/{counts[k][1]}" if k in counts else "·" for k in ("matching", "bare", "mismatched")]
        print(f"| {task} | {len(chunks[task])} | " + " | ".join(cells) + " |")
    for task in sorted(t for t in chunks if t.startswith("Rotate")):
        turns = [turn for chunk in chunks[task] for turn in peg_turns(chunk)]
        asked = np.array([t[0] for t in turns], dtype=float)
        final = np.array([t[1] for t in turns])
        # the peg's halves look alike: a turn is as good as itself plus or minus 180 degrees
        off = np.abs((final - asked + 90) % 180 - 90)
        print(f"\n{task}: {len(turns)} episodes told the true fact; the peg turned {np.median(np.abs(final)):.1f} "
              f"degrees (median, either way) for a median {np.median(np.abs(asked)):.0f} asked; "
              f"{np.mean(np.sign(final) == np.sign(asked)):.0%} turned the way asked; ended within 5.7 degrees of "
              f"the rotation (modulo 180): {np.mean(off <= 5.7):.0%}")


if __name__ == "__main__":
    main()
