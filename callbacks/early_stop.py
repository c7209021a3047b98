"""Stop training once the held-out retrieval has reached a target: the learner retrieves the true memory greedily
on the development seeds, evaluation after evaluation, so further rounds only cost time (a learner per benchmark
task trains for its zoo budget otherwise: hours a task on a CPU)."""

from __future__ import annotations

import json
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sb3_memret.callbacks.evaluation import RetrievalEvalCallback


class StopOnRetrievalTarget(BaseCallback):
    """Ends ``model.learn`` once the held-out evaluations (the ``evaluator``'s, which this registers with) of
    ``patience`` rounds in a row had greedy accuracy of at least ``greedy_accuracy``, as SB3's ``StopTrainingOn...``
    callbacks end it: the next step returns False. A resumed run counts the streak its history ends with; a round
    evaluated twice (a run resumed within it) counts once.

    ``reached`` is the round at which the target was met; ``stopped`` the round at which that ended training (None
    if training ran to its budget: a target first met by the final evaluation stops nothing)."""

    def __init__(self, evaluator: RetrievalEvalCallback, greedy_accuracy: float, patience: int = 2, verbose: int = 0):
        super().__init__(verbose)
        if not 0.0 < greedy_accuracy <= 1.0:
            raise ValueError(f"greedy_accuracy must be in (0, 1], got {greedy_accuracy}")
        if patience < 1:
            raise ValueError(f"patience must be >= 1 evaluation, got {patience}")
        self.evaluator, self.greedy_accuracy, self.patience = evaluator, greedy_accuracy, patience
        self.streak, self._last_round = 0, -1
        self.reached: int | None = None
        self.stopped: int | None = None
        evaluator.listeners.append(self)

    def _init_callback(self) -> None:
        history = self.evaluator.history_path
        if history is not None and history.exists():  # a resumed run: the evaluations it already played
            for row in (json.loads(line) for line in history.read_text().splitlines() if line.strip()):
                self._count(row["greedy_accuracy"], row["round"])

    def _count(self, greedy_accuracy: float, round_: int) -> None:
        if round_ == self._last_round:  # the same policy again (a run resumed within its round): no new evidence
            return
        self._last_round = round_
        self.streak = self.streak + 1 if greedy_accuracy >= self.greedy_accuracy else 0
        if self.streak >= self.patience and self.reached is None:
            self.reached = round_

    def _on_step(self) -> bool:
        if self.reached is None:
            return True
        self.stopped = self.reached
        if self.verbose:
            print(f"stopping: held-out greedy accuracy >= {self.greedy_accuracy:.0%} in {self.patience} evaluations "
                  f"in a row (round {self.reached})")
        return False

    # ------------------------------------------------------------------ RetrievalEvalCallback calls these
    def evaluation_started(self, round_: int, episodes: int) -> None:
        pass

    def evaluation_episode(self) -> None:
        pass

    def evaluation_finished(self, report: Any = None) -> None:
        if report is not None:
            self._count(report.greedy_accuracy, self.evaluator.round)


__all__ = ["StopOnRetrievalTarget"]
