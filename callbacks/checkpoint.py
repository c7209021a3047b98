"""Checkpoints taken after each PPO update, so a resumed run loses no finished round."""

from __future__ import annotations

import os
import re
from pathlib import Path

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

from sb3_memret.common.workers import stop_signals_deferred

CHECKPOINT_PATTERN = re.compile(r"^memret_(\d+)_steps\.zip$")


def save_whole(model: BaseAlgorithm, path: Path) -> None:
    """``model.save(path)`` that a stop signal cannot cut short (it waits until the file is written) and
    that a kill cannot leave half-written (the file is written beside and renamed into place)."""
    partial = path.with_name(path.stem + ".partial.zip")
    with stop_signals_deferred():
        model.save(partial)
        os.replace(partial, path)


def checkpoint_path(folder: str | Path, num_timesteps: int) -> Path:
    return Path(folder) / f"memret_{num_timesteps}_steps.zip"


def checkpoints(folder: str | Path) -> list[tuple[int, Path]]:
    """(timesteps, path) of every checkpoint in ``folder``, oldest first."""
    return sorted((int(m.group(1)), p) for p in Path(folder).glob("memret_*_steps.zip")
                  if (m := CHECKPOINT_PATTERN.match(p.name)))


def latest_checkpoint(folder: str | Path) -> Path | None:
    """The checkpoint in ``folder`` with the most timesteps, or None if there is none."""
    found = checkpoints(folder)
    return found[-1][1] if found else None


class RoundCheckpointCallback(BaseCallback):
    """Saves the model every ``every`` rounds, right after the update (SB3's CheckpointCallback
    saves on the last collection step, before it), and keeps the newest ``keep`` files."""

    def __init__(self, save_path: str | Path, every: int = 1, keep: int = 3, verbose: int = 0):
        super().__init__(verbose)
        if every < 1 or keep < 1:
            raise ValueError(f"every and keep must be >= 1, got every={every}, keep={keep}")
        self.save_path, self.every, self.keep = Path(save_path), every, keep
        self._rounds = 0

    def _init_callback(self) -> None:
        self.save_path.mkdir(parents=True, exist_ok=True)

    def _on_rollout_start(self) -> None:
        if self.num_timesteps > 0 and self._rounds % self.every == 0:
            self.save()
        self._rounds += 1

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self.save()

    def save(self) -> Path:
        """Save now (also used when a run is interrupted) and prune old checkpoints."""
        path = checkpoint_path(self.save_path, self.model.num_timesteps)
        save_whole(self.model, path)
        if self.verbose:
            print(f"checkpoint: {path}")
        for _, old in checkpoints(self.save_path)[: -self.keep]:
            old.unlink()
        return path
