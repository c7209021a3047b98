"""Held-out retrieval evaluation every few rounds, with best-model saving and a JSON-lines history."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import HumanOutputFormat
from stable_baselines3.common.vec_env import VecEnv

from sb3_memret.evaluation.retrieval import RetrievalReport, evaluate_retrieval
from sb3_memret.callbacks.checkpoint import save_whole


GROUP_KEY = "success_group_"  # per-group success (a drawer layer, a task of a run across tasks)


class RetrievalEvalCallback(BaseCallback):
    """Evaluates the current policy greedily on held-out seeds at the start of every
    ``eval_every``-th round (so row r of the log describes the policy after r updates, the same
    policy that collects round r) and once more when training ends. Round 0's evaluation plays
    ``n_initial_episodes`` (default ``n_eval_episodes``): the untrained learner's episodes cost the most; the
    final one ``n_final_episodes`` (default ``n_eval_episodes``): many cheap points make the curve, one larger
    evaluation the final figure (the report plays its baselines on the same episodes).

    Logs ``eval/*`` (greedy accuracy, sampled fraction, entropy, success overall and per group,
    shaped return and reward, true-memory eviction rate) through the model's logger (per-group success leaves the
    stdout table when SB3 would cut two of its keys to the same text: 32 task names), appends
    every report to ``history_path`` and saves ``best_model.zip`` when a policy beats the best
    so far on (greedy accuracy, success, sampled fraction).
    """

    def __init__(self, eval_env: VecEnv, n_eval_episodes: int = 50, eval_seed: int = 1_000_000, eval_every: int = 1,
                 best_model_save_path: str | Path | None = None, history_path: str | Path | None = None,
                 verbose: int = 0, n_initial_episodes: int | None = None, n_final_episodes: int | None = None):
        super().__init__(verbose)
        n_initial_episodes = n_eval_episodes if n_initial_episodes is None else n_initial_episodes
        n_final_episodes = n_eval_episodes if n_final_episodes is None else n_final_episodes
        if min(n_eval_episodes, n_initial_episodes, n_final_episodes, eval_every) < 1:
            raise ValueError(f"n_eval_episodes, n_initial_episodes, n_final_episodes and eval_every must be >= 1, got "
                             f"{n_eval_episodes}, {n_initial_episodes}, {n_final_episodes}, {eval_every}")
        self.eval_env, self.n_eval_episodes, self.eval_seed = eval_env, n_eval_episodes, eval_seed
        self.n_initial_episodes, self.n_final_episodes = n_initial_episodes, n_final_episodes
        self.eval_every = eval_every
        self.best_model_save_path = Path(best_model_save_path) if best_model_save_path else None
        self.history_path = Path(history_path) if history_path else None
        self.best_key: tuple[float, float, float] | None = None
        self.last_report: RetrievalReport | None = None
        self._evaluated_round = -1
        # told when an evaluation starts, finishes an episode, and ends with its report (None if it failed):
        # a progress bar, a hyperparameter search that prunes on the reports
        self.listeners: list[Any] = []

    @property
    def round(self) -> int:
        """PPO updates applied so far (survives save/load through ``_n_updates``)."""
        return self.model._n_updates // self.model.n_epochs

    def _init_callback(self) -> None:
        for path in (self.best_model_save_path, self.history_path and self.history_path.parent):
            if path:
                path.mkdir(parents=True, exist_ok=True)
        if self.history_path and self.history_path.exists():
            rows = [json.loads(line) for line in self.history_path.read_text().splitlines() if line.strip()]
            if rows:  # a resumed run keeps competing against its earlier best
                best = max(rows, key=_key)
                self.best_key = _key(best)

    def _on_rollout_start(self) -> None:
        if self.round % self.eval_every == 0:
            self.evaluate()

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        if self._evaluated_round != self.round:
            self.evaluate(final=True)
            self.logger.dump(self.num_timesteps)

    def episodes_left(self, final_timesteps: int) -> int:
        """Held-out episodes still to play before training reaches ``final_timesteps`` (the evaluation under
        way, if any, not counted): one evaluation every ``eval_every`` rounds still to start, and the last."""
        round_size = self.model.n_steps * self.model.get_env().num_envs
        last = math.ceil(final_timesteps / round_size)  # the round training ends at
        later = sum(1 for r in range(self.round + 1, last) if r % self.eval_every == 0)
        return later * self.n_eval_episodes + self.n_final_episodes

    def _stdout_collides(self, metrics: dict[str, Any]) -> bool:
        """Whether SB3's stdout table, which cuts keys to its ``max_length``, would show two of ``metrics`` alike
        (and refuse the whole dump): ``success_group_BlinkCountButtonPressEasy-VLA-v0`` and ``...Medium...``."""
        widths = [f.max_length for f in self.logger.output_formats if isinstance(f, HumanOutputFormat)]
        if not widths:
            return False
        width = min(widths)
        shown = ["   " + key.split("/", 1)[1] for key in metrics]  # SB3 indents a key under its tag
        shown = [key if len(key) <= width else key[:width - 3] for key in shown]
        return len(set(shown)) < len(shown)

    def evaluate(self, final: bool = False) -> RetrievalReport:
        """Play one held-out evaluation of the current policy (``final``: the one at training's end) and log it."""
        start = time.perf_counter()
        episodes = (self.n_final_episodes if final else self.n_initial_episodes if self.round == 0
                    else self.n_eval_episodes)
        for listener in self.listeners:
            listener.evaluation_started(self.round, episodes)
        try:
            report = evaluate_retrieval(  # training chooses on development seeds, never the protocol's
                self.model, self.eval_env, episodes, seed=self.eval_seed, held_out="development",
                on_episode=lambda _: [listener.evaluation_episode() for listener in self.listeners])
        except BaseException:
            for listener in self.listeners:
                listener.evaluation_finished(None)
            raise
        self._evaluated_round, self.last_report = self.round, report
        metrics = {f"eval/{key}": value for key, value in report.as_metrics().items()}
        hidden = ("stdout",) if self._stdout_collides(metrics) else None
        for key, value in metrics.items():
            self.logger.record(key, value, exclude=hidden if GROUP_KEY in key else None)
        self.logger.record("eval/round", self.round)
        self.logger.record("eval/seconds", time.perf_counter() - start)
        row = {"round": self.round, "timesteps": self.num_timesteps, **report.to_dict()}
        if self.history_path:
            with self.history_path.open("a") as f:
                f.write(json.dumps(row) + "\n")
        if self.best_key is None or _key(row) > self.best_key:
            self.best_key = _key(row)
            if self.best_model_save_path:
                save_whole(self.model, self.best_model_save_path / "best_model.zip")
        for listener in self.listeners:  # after the history and best model are saved: a listener may stop the run
            listener.evaluation_finished(report)
        if self.verbose:
            print(f"round {self.round}: greedy {report.greedy_accuracy:.0%}, sampled {report.sampled_fraction:.0%}, "
                  f"entropy {report.entropy:.2f}, success {report.success['overall']:.0%}")
        return report


def _key(row: dict) -> tuple[float, float, float]:
    return row["greedy_accuracy"], row["success"]["overall"], row["sampled_fraction"]
