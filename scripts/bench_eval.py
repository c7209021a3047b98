"""Evaluation throughput with n parallel envs against one env, measured in the same run.

Two evaluation paths, each timed end to end (worker start-up included, as a user waits for it):

- controller episodes (``sb3-memret ablate``): ``run_jobs`` playing oracle-prompt episodes
  on every layer, 1 env in-process vs n worker processes;
- policy evaluation (``sb3-memret eval``, the training-time evaluation): ``evaluate_retrieval``
  of an untrained memory policy on the recall env, a 1-env vs an n-env VecEnv.

The controller path plays the same placements at every n, so its speed-up is pure throughput.
The policy path splits episodes over the envs as SB3's ``evaluate_policy`` does (env i draws
from seed + i), so its episodes differ between n and its speed-up is taken on decisions per
second. Usage:
``python scripts/bench_eval.py [--episodes N] [--n-envs 2 4 ...]``.
"""

from __future__ import annotations

import argparse
import os
import time

import torch

from sb3_memret.envs.cabinet import LAYERS
from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.evaluation import evaluate_retrieval
from sb3_memret.parallel_rollout import EpisodeJob, run_jobs
from sb3_memret.policy.policy import MemoryRetrievalPolicy
from sb3_memret.policy.ppo import MemRetPPO
from sb3_memret.prompts import condition_prompt

SEED = 1_000_000


def controller_episodes(n_envs: int, episodes: int) -> tuple[float, int]:
    """Seconds and control steps for ``episodes`` oracle episodes spread over the layers."""
    jobs = [EpisodeJob(condition_prompt("oracle", LAYERS[k % 3]), LAYERS[k % 3], SEED + k) for k in range(episodes)]
    start = time.perf_counter()
    results = run_jobs("scripted", jobs, n_envs)
    return time.perf_counter() - start, sum(r.steps for r in results)


def policy_evaluation(n_envs: int, episodes: int) -> tuple[float, int]:
    """Seconds and decisions for ``evaluate_retrieval`` of an untrained policy over ``episodes``."""
    start = time.perf_counter()
    venv = make_recall_vec_env(n_envs, {"controller": "scripted"})
    try:
        model = MemRetPPO(MemoryRetrievalPolicy, venv, seed=0, device="cpu")
        report = evaluate_retrieval(model, venv, episodes, seed=SEED)
    finally:
        venv.close()
    return time.perf_counter() - start, report.decisions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=12, help="episodes per measurement")
    parser.add_argument("--n-envs", type=int, nargs="+", default=[os.cpu_count() or 2])
    args = parser.parse_args()
    torch.set_num_threads(1)  # as in a worker, so 1 env and n envs compute alike
    print(f"{os.cpu_count()} CPU cores, {args.episodes} episodes per measurement (same placements at every n)\n")
    print("| path | envs | seconds | episodes/s | unit/s | speed-up vs 1 env |")
    print("|---|---|---|---|---|---|")
    for name, measure, unit in (("controller episodes (ablate)", controller_episodes, "steps"),
                                ("policy evaluation (eval)", policy_evaluation, "decisions")):
        base_seconds, base_units = measure(1, args.episodes)
        print(f"| {name} | 1 | {base_seconds:.1f} | {args.episodes / base_seconds:.2f} | "
              f"{base_units / base_seconds:.0f} {unit} | 1.00 |")
        for n in args.n_envs:
            seconds, units = measure(n, args.episodes)
            print(f"| {name} | {n} | {seconds:.1f} | {args.episodes / seconds:.2f} | {units / seconds:.0f} {unit} | "
                  f"{(units / seconds) / (base_units / base_seconds):.2f} |")


if __name__ == "__main__":
    main()
