"""What drawing a finetune's batch by error costs (``training.priority``, ``FrameSampler``): milliseconds per training
step (one draw and one update of the drawn frames' errors) over a split of N frames, for the uniform draw, the
sampler's draw by error, and numpy's weighted choice without replacement (``rng.choice(p=...)``) on the same
weights as a baseline, taking turns. The 34-task camera finetune draws from about 177,000 training frames (of 196,666)
at about 180 ms a step.

Usage: ``python scripts/bench_frame_sampler.py [--frames 180000] [--batch 256] [--priority 1.0] [--steps 30]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from sb3_memret.stage1.sampling import FrameSampler


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=180_000)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--priority", type=float, default=1.0)
    parser.add_argument("--steps", type=int, default=30)
    args = parser.parse_args()
    frames, rng = np.arange(args.frames), np.random.default_rng(0)
    uniform, by_error = FrameSampler(frames), FrameSampler(frames, args.priority)
    by_error.update(frames, rng.gamma(2.0, 0.03, args.frames))  # errors spread as a finetune's are

    def numpy_choice() -> np.ndarray:
        return rng.choice(frames, size=args.batch, replace=False, p=by_error.probabilities())

    ways = {"uniform": lambda: uniform.draw(rng, args.batch), "by error": lambda: by_error.draw(rng, args.batch),
            "numpy weighted choice": numpy_choice}
    seconds = {name: 0.0 for name in ways}
    for _ in range(args.steps):
        for name, draw in ways.items():
            started = time.perf_counter()
            batch = draw()
            if name != "uniform":
                by_error.update(batch, rng.gamma(2.0, 0.03, len(batch)))
            seconds[name] += time.perf_counter() - started
    base = seconds["numpy weighted choice"]
    print(f"{args.frames} frames, batch {args.batch}, priority {args.priority}, {args.steps} steps each")
    for name, total in seconds.items():
        print(f"  {name:>22}: {1000 * total / args.steps:7.2f} ms a step  ({total / base:.2f}x numpy's weighted choice)")


if __name__ == "__main__":
    main()
