"""Where a run's training time goes: collecting decisions, PPO updates, held-out evaluations.

``PhaseTimingCallback`` splits the wall time of ``model.learn`` into those three parts, so a run's
``summary.json`` can say what a shorter run should cut (``scripts/bench_main_job.py`` prints the split).
"""

from __future__ import annotations

import time
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sb3_memret.callbacks.evaluation import RetrievalEvalCallback


class PhaseTimingCallback(BaseCallback):
    """Seconds spent collecting rollouts (the training decisions), in PPO's updates and in the held-out
    evaluations of ``evaluator`` (whose listener it becomes), and seconds per evaluation by round.

    Collection is timed from each rollout's start to its end; an update is what lies between the end of one
    rollout and the start of the next (or the end of training); either is less any evaluation played within it,
    so the split holds wherever the callback stands in the list beside the evaluator.
    """

    def __init__(self, evaluator: RetrievalEvalCallback | None = None):
        super().__init__()
        self.collect_seconds = self.update_seconds = self.eval_seconds = 0.0
        self.eval_rounds: dict[int, float] = {}  # seconds of each evaluation, by round
        self._collect_start: float | None = None
        self._update_start: float | None = None
        self._eval_start: float | None = None
        self._eval_round = -1
        self._eval_since_mark = 0.0  # evaluation seconds played since the current collection or update began
        if evaluator is not None:
            evaluator.listeners.append(self)

    def _on_rollout_start(self) -> None:
        self._close_update()
        self._collect_start, self._eval_since_mark = time.perf_counter(), 0.0

    def _on_rollout_end(self) -> None:
        if self._collect_start is not None:
            self.collect_seconds += time.perf_counter() - self._collect_start - self._eval_since_mark
            self._collect_start = None
        self._update_start, self._eval_since_mark = time.perf_counter(), 0.0

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self._close_update()

    def _close_update(self) -> None:
        if self._update_start is not None:
            self.update_seconds += time.perf_counter() - self._update_start - self._eval_since_mark
            self._update_start = None

    # RetrievalEvalCallback calls these
    def evaluation_started(self, round_: int, episodes: int) -> None:
        self._eval_start, self._eval_round = time.perf_counter(), round_

    def evaluation_episode(self) -> None:
        pass

    def evaluation_finished(self, report: Any = None) -> None:
        if self._eval_start is None:
            return
        seconds = time.perf_counter() - self._eval_start
        self._eval_start = None
        self.eval_seconds += seconds
        self._eval_since_mark += seconds
        self.eval_rounds[self._eval_round] = self.eval_rounds.get(self._eval_round, 0.0) + seconds

    def split(self) -> dict[str, Any]:
        """The seconds so far: ``collect``, ``update``, ``evaluate`` and ``evaluate_by_round``."""
        return {"collect": self.collect_seconds, "update": self.update_seconds, "evaluate": self.eval_seconds,
                "evaluate_by_round": {str(r): s for r, s in sorted(self.eval_rounds.items())}}


__all__ = ["PhaseTimingCallback"]
