"""One progress bar for a whole run: training decisions and the held-out evaluations between them.

SB3's own bar counts environment steps only, so it stalls while an evaluation plays its episodes and its
time left ignores them. This bar names what is running, counts evaluation episodes as they finish, and
estimates the time left from both measured rates: training decisions per second, and seconds per
evaluation episode.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

from stable_baselines3.common.callbacks import BaseCallback
from tqdm import tqdm

from sb3_memret.callbacks.evaluation import RetrievalEvalCallback


class RunProgressCallback(BaseCallback):
    """A tqdm bar over the run's decisions whose description says whether it trains or evaluates, and whose
    postfix gives the training rate (decisions/s) and the time left, evaluations included.

    Put it beside the ``evaluator`` whose evaluations it follows (it registers itself with it)."""

    def __init__(self, evaluator: RetrievalEvalCallback | None = None, file: TextIO | None = None,
                 mininterval: float = 0.5):
        super().__init__()
        self.evaluator, self.file, self.mininterval = evaluator, file or sys.stderr, mininterval
        self.bar: tqdm | None = None
        self.train_seconds = self.eval_seconds = 0.0
        self.trained = self.eval_episodes_done = 0
        self._since: float | None = None  # when the current stretch of training began
        self._eval_started: float | None = None
        if evaluator is not None:
            evaluator.listeners.append(self)

    # ------------------------------------------------------------------ training
    def _on_training_start(self) -> None:
        self.total = self.locals["total_timesteps"] - self.model.num_timesteps
        self.bar = tqdm(total=self.total, unit="decision", file=self.file, mininterval=self.mininterval,
                        dynamic_ncols=True, bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} "
                                                       "decisions [{elapsed}{postfix}]")
        self._describe("training")
        self._since = time.perf_counter()

    def _on_rollout_start(self) -> None:
        self._describe(f"training round {self.model._n_updates // max(self.model.n_epochs, 1)}")

    def _on_step(self) -> bool:
        if self._since is None:
            self._since = time.perf_counter()
        self.trained += self.training_env.num_envs
        self._postfix(refresh=False)  # update() redraws at most every mininterval
        self.bar.update(self.training_env.num_envs)
        return True

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.set_description_str("done", refresh=False)
            rate = self.rate()
            self.bar.set_postfix_str(f"{rate:.1f} decisions/s" if rate else "", refresh=False)
            self.bar.close()

    # ------------------------------------------------------------------ evaluations (RetrievalEvalCallback calls these)
    def evaluation_started(self, round_: int, episodes: int) -> None:
        if self._since is not None:
            self.train_seconds += time.perf_counter() - self._since
            self._since = None
        self._eval_started, self._eval_done, self._eval_total = time.perf_counter(), 0, episodes
        self._describe(f"evaluating round {round_}: 0/{episodes} episodes")

    def evaluation_episode(self) -> None:
        self._eval_done += 1
        self.eval_episodes_done += 1
        self._describe(f"evaluating: {self._eval_done}/{self._eval_total} episodes")

    def evaluation_finished(self, report: Any = None) -> None:
        self.eval_seconds += time.perf_counter() - self._eval_started
        self._describe("training")

    # ------------------------------------------------------------------ display
    def _describe(self, text: str) -> None:
        if self.bar is not None:
            self.bar.set_description_str(text, refresh=False)
            self._postfix()

    def rate(self) -> float | None:
        """Training decisions per second, evaluations left out (None before the first decision)."""
        seconds = self.train_seconds + self._running()
        return self.trained / seconds if self.trained and seconds > 0 else None

    def seconds_left(self) -> float | None:
        """Training decisions left at the measured rate, plus the evaluations still to come at the measured
        seconds per episode (None until both rates are known)."""
        rate = self.rate()
        if self.bar is None or rate is None:
            return None
        left = (self.total - self.bar.n) / rate
        if self.evaluator is not None:
            if not self.eval_episodes_done:
                return None
            per_episode = self.eval_seconds / self.eval_episodes_done
            left += self.evaluator.episodes_left(self.model.num_timesteps + self.total - self.bar.n) * per_episode
        return left

    def _running(self) -> float:
        return time.perf_counter() - self._since if self._since is not None else 0.0

    def _postfix(self, refresh: bool = True) -> None:
        rate, left = self.rate(), self.seconds_left()
        parts = [f"{rate:.1f} decisions/s"] if rate is not None else []
        parts.append(f"~{tqdm.format_interval(left)} left" if left is not None else "time left: after an evaluation")
        self.bar.set_postfix_str(", ".join(parts), refresh=refresh)


__all__ = ["RunProgressCallback"]
