"""What a task's camera demonstrations cost to record, three ways measured in the same run on the same seeds:
every control step kept (``--frames every``), the decision steps only with the cameras paused between them (``demos``'
default), and the decision steps only with every step rendered (the recorder before it paused the cameras). It
prints CPU seconds per episode (this process's, so the figure holds on a busy machine) and each way's ratio to every
step kept. Every episode's labels and outcome are checked equal across the ways: pausing the cameras changes
none.

    python scripts/bench_demos.py [--task RememberColor3-VLA-v0] [--episodes 5] [--seed 900000]

No dataset is written: the cost of LeRobot's writer (PNG files, per-episode statistics) comes on top, and grows with
the frames kept. The seeds are demonstration seeds, never the benchmark's.
"""

from __future__ import annotations

import argparse
import time

from sb3_memret.stage1.demos import DemoRecorder
from sb3_memret.tasks.demos import DemoEpisode


def record(task: str, frames: str, episodes: list[DemoEpisode], paused: bool) -> tuple[float, list]:
    """CPU seconds per episode and the episodes recorded, with a fresh recorder (its start-up not counted)."""
    recorder = DemoRecorder(task, "cpu", frames=frames)
    if not paused:
        recorder.pause = None
    try:
        recorder.record(episodes[0])  # warm-up: the renderer's first picture, the expert's first call
        start = time.process_time()
        recorded = [recorder.record(episode) for episode in episodes]
        return (time.process_time() - start) / len(episodes), recorded
    finally:
        recorder.env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="RememberColor3-VLA-v0")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=900_000)
    args = parser.parse_args()
    episodes = [DemoEpisode(args.seed + i, "matching") for i in range(args.episodes)]
    ways = [("every step kept", "every", True), ("decisions, cameras paused between", "decisions", True),
            ("decisions, every step rendered", "decisions", False)]
    results = {name: record(args.task, frames, episodes, paused) for name, frames, paused in ways}
    baseline = results[ways[0][0]][0]
    print(f"{args.task}, {args.episodes} episodes from seed {args.seed}, CPU seconds per episode:")
    for name, (seconds, recorded) in results.items():
        frames = sum(len(r.frames) for r in recorded)
        print(f"  {name:36s} {seconds:6.2f} s  ({baseline / seconds:4.2f}x every step kept; {frames} frames kept)")
    outcomes = [[(r.success, r.actions.tobytes()) for r in recorded] for _, recorded in results.values()]
    assert all(o == outcomes[0] for o in outcomes), "an episode's labels or outcome differ between the ways"
    print(f"  labels and outcomes equal across the ways: {sum(s for s, _ in outcomes[0])}/{args.episodes} succeeded")

if __name__ == "__main__":
    main()
