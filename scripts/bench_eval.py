"""Evaluation throughput with n parallel envs against one env, measured in the same run.

Two evaluation paths:

- controller episodes (``sb3-memret ablate``): ``run_jobs`` playing oracle-prompt episodes
  on every layer, 1 env in-process vs n physics worker processes served by one controller;
- policy evaluation (``sb3-memret eval``, the training-time evaluation): ``evaluate_retrieval``
  of an untrained memory policy on the recall env, a 1-env vs an n-env RecallVecEnv.

Each is timed end to end (start-up included, as a user waits for it) and in steady state:
the rate of the episodes that end after every env has ended its first one, which leaves out
building the envs and starting the workers. The controller path plays the same placements
at every n; the policy path splits episodes over the envs as SB3's ``evaluate_policy`` does
(env i draws from seed + i), so its rates are taken on decisions per second. Usage:
``python scripts/bench_eval.py [--episodes N] [--n-envs 2 4 ...]``.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass

import torch

from sb3_memret.tasks.drawer.cabinet import LAYERS
from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.evaluation.retrieval import evaluate_retrieval
from sb3_memret.evaluation.parallel import EpisodeJob, run_jobs
from sb3_memret.policy.policy import MemoryRetrievalPolicy
from sb3_memret.policy.ppo import MemRetPPO
from sb3_memret.tasks.drawer.prompts import condition_prompt
from sb3_memret.evaluation.rollout import EpisodeResult

SEED = 1_000_000


@dataclass
class Timing:
    """When each episode ended (seconds from the start) and how much work (steps, decisions) it held."""

    ends: list[float]
    work: list[int]

    @property
    def total_rate(self) -> float:
        return sum(self.work) / self.ends[-1]

    def steady_rate(self, n_envs: int) -> float:
        """Work per second over the episodes ending after the n_envs-th one."""
        return sum(self.work[n_envs:]) / (self.ends[-1] - self.ends[n_envs - 1])


def controller_episodes(n_envs: int, episodes: int) -> Timing:
    """Oracle episodes spread over the layers; work = control steps."""
    jobs = [EpisodeJob(condition_prompt("oracle", LAYERS[k % 3]), SEED + k, {"target_layer": LAYERS[k % 3]})
            for k in range(episodes)]
    timing, start = Timing([], []), time.perf_counter()

    def record(job: EpisodeJob, result: EpisodeResult) -> None:
        timing.ends.append(time.perf_counter() - start)
        timing.work.append(result.steps)

    run_jobs("scripted", jobs, "drawer", n_envs, on_result=record)
    return timing


def policy_evaluation(n_envs: int, episodes: int) -> Timing:
    """``evaluate_retrieval`` of an untrained policy; work = decisions."""
    timing, start = Timing([], []), time.perf_counter()

    def record(episode: dict) -> None:
        timing.ends.append(time.perf_counter() - start)
        timing.work.append(episode["decisions"])

    venv = make_recall_vec_env(n_envs, {"controller": "scripted"})
    try:
        model = MemRetPPO(MemoryRetrievalPolicy, venv, seed=0, device="cpu")
        evaluate_retrieval(model, venv, episodes, seed=SEED, on_episode=record)
    finally:
        venv.close()
    return timing


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=24, help="episodes per measurement")
    parser.add_argument("--n-envs", type=int, nargs="+", default=[os.cpu_count() or 2])
    args = parser.parse_args()
    torch.set_num_threads(1)  # as in a worker, so 1 env and n envs compute alike
    print(f"{os.cpu_count()} CPU cores, {args.episodes} episodes per measurement\n")
    print("| path | envs | wall s | episodes/s | work/s (end to end) | speed-up | work/s (steady) | speed-up |")
    print("|---|---|---|---|---|---|---|---|")
    for name, measure, unit in (("controller episodes (ablate)", controller_episodes, "steps"),
                                ("policy evaluation (eval)", policy_evaluation, "decisions")):
        base = measure(1, args.episodes)
        for n in [1, *args.n_envs]:
            timing = base if n == 1 else measure(n, args.episodes)
            print(f"| {name} | {n} | {timing.ends[-1]:.1f} | {len(timing.ends) / timing.ends[-1]:.2f} | "
                  f"{timing.total_rate:.0f} {unit} | {timing.total_rate / base.total_rate:.2f} | "
                  f"{timing.steady_rate(n):.0f} {unit} | {timing.steady_rate(n) / base.steady_rate(1):.2f} |")


if __name__ == "__main__":
    main()
