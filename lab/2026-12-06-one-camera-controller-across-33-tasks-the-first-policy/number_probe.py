"""Can the learned controller's prompt input tell Rotate's numbers apart? A ridge probe from MiniLM's per-token
features of Rotate prompts (what the network's attention pool reads) to the rotation asked and the start angle.

    .venv/bin/python lab/2026-12-06-one-camera-controller-across-33-tasks-the-first-policy/number_probe.py
"""

from __future__ import annotations

import numpy as np

from sb3_memret.memory.encoder import MiniLMEncoder


def ridge(x_train: np.ndarray, y_train: np.ndarray, x_test: np.ndarray, lam: float) -> np.ndarray:
    mean, target_mean = x_train.mean(0), y_train.mean(0)
    centred = x_train - mean
    weights = np.linalg.solve(centred.T @ centred + lam * np.eye(centred.shape[1]), centred.T @ (y_train - target_mean))
    return (x_test - mean) @ weights + target_mean


def main(n: int = 1500, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    values = [(int(rng.integers(6, 91)), int(rng.integers(0, 180))) for _ in range(n)]
    prompts = [f"rotate the peg by {a} degrees to match the target angle. the peg started at {s} degrees."
               for a, s in values]
    features = MiniLMEncoder().encode_tokens(prompts)
    if len({len(f) for f in features}) != 1:
        raise SystemExit("the prompts tokenise to different lengths: the probe flattens one token layout")
    x = np.stack([f.reshape(-1) for f in features])
    y = np.array(values, dtype=float)
    order = rng.permutation(n)
    train, test = order[: int(0.8 * n)], order[int(0.8 * n):]
    error = np.abs(ridge(x[train], y[train], x[test], 0.1) - y[test])
    print(f"values seen in training: mean absolute error {error[:, 0].mean():.1f} degrees (rotation), "
          f"{error[:, 1].mean():.1f} (start)")
    unseen = np.array([a % 5 == 0 or s % 5 == 0 for a, s in values])
    error = np.abs(ridge(x[~unseen], y[~unseen], x[unseen], 1.0) - y[unseen])
    print(f"values never seen (multiples of 5 held out): {error[:, 0].mean():.1f} (rotation), "
          f"{error[:, 1].mean():.1f} (start)")


if __name__ == "__main__":
    main()
