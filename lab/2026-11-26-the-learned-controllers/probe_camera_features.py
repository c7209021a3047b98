"""How much of the target's pose can a camera encoder read? A probe for the drawer's camera controller.

Trains a camera head (the learned controller's, on the frozen trunk's features or on pixels) to regress the
target's position and yaw from both cameras, on the demonstration frames where the target is in sight, and
prints R^2 on held-out episodes beside the mean-predicting baseline (R^2 = 0). The pose comes from the
dataset's full state (the simulator's detection): a label for this probe only, never a controller's input.

    python lab/2026-11-26-the-learned-controllers/probe_camera_features.py runs/stage1-camera/demos --encoder efficientnet_lite0 --steps 1500
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from torch import nn

from sb3_memret.controllers.learned.vision import make_camera_encoder, shift_augment
from sb3_memret.controllers.observation import IMAGE_KEYS, STATE_NAMES
from sb3_memret.stage1.datasets import load_demonstrations

TARGETS = ("x", "y", "z", "yaw")


def target_pose(states: np.ndarray) -> np.ndarray:
    """(N, 4) position and yaw (radians) of the detected target from the drawer's 19-D state."""
    at = {name: states[:, STATE_NAMES.index(name)] for name in STATE_NAMES}
    w, x, y, z = at["target_qw"], at["target_qx"], at["target_qy"], at["target_qz"]
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([at["target_x"], at["target_y"], at["target_z"], yaw], axis=1).astype(np.float32)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("--encoder", default="efficientnet_lite0", choices=["cnn", "efficientnet_lite0"])
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)

    demos = load_demonstrations([args.dataset])
    seen = demos.states[:, STATE_NAMES.index("target_visible")] > 0.5
    index = np.flatnonzero(seen)
    pose = target_pose(demos.states[index])
    mean, std = pose.mean(0), pose.std(0) + 1e-6
    labels = torch.from_numpy((pose - mean) / std)
    episodes = demos.episodes[index]
    held_out = np.isin(episodes, rng.choice(np.unique(episodes), size=max(1, len(np.unique(episodes)) // 10),
                                            replace=False))
    train, test = np.flatnonzero(~held_out), np.flatnonzero(held_out)
    print(f"{len(index)} frames with the target in sight ({len(test)} held out); pose std {np.round(std, 3)}")

    started = time.monotonic()
    heads, inputs = [], []
    for key in IMAGE_KEYS:
        trunk, head = make_camera_encoder(args.encoder, 64)
        images = torch.from_numpy(demos.images[key][index]).permute(0, 3, 1, 2)
        if trunk is not None:
            images = torch.cat([trunk(images[i: i + 64].float() / 255.0).half() for i in range(0, len(images), 64)])
        heads.append(head)
        inputs.append(images)
    model = nn.ModuleDict({"heads": nn.ModuleList(heads), "out": nn.Linear(64 * len(heads), len(TARGETS))})
    optimizer = torch.optim.AdamW(model.parameters(), lr=1e-3)

    def predict(idx: np.ndarray, augment: bool) -> torch.Tensor:
        parts = []
        for head, x in zip(model["heads"], inputs):
            batch = x[idx].float() / (255.0 if args.encoder == "cnn" else 1.0)
            parts.append(head(shift_augment(batch, 4) if augment and args.encoder == "cnn" else batch))
        return model["out"](torch.cat(parts, dim=1))

    for step in range(args.steps):
        batch = rng.choice(train, size=min(args.batch_size, len(train)), replace=False)
        loss = (predict(batch, True) - labels[batch]).square().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        predicted = torch.cat([predict(test[i: i + 256], False) for i in range(0, len(test), 256)])
    residual = (predicted - labels[test]).square().mean(0)
    baseline = (labels[test] - labels[train].mean(0)).square().mean(0)
    r2 = 1 - residual / baseline
    rmse = residual.sqrt().numpy() * std
    print(f"encoder {args.encoder}: {args.steps} steps in {time.monotonic() - started:.0f} s")
    for name, score, error in zip(TARGETS, r2.tolist(), rmse):
        unit = "deg" if name == "yaw" else "cm"
        print(f"  {name:>4}: held-out R^2 {score:.2f}, RMSE {np.degrees(error) if name == 'yaw' else 100 * error:.1f} {unit}")


if __name__ == "__main__":
    main()
