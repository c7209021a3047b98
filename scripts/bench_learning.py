"""Learning benchmark: train the memory learner from random initialisation on the real
simulator (scripted controller, recall mode) and report, per round, greedy accuracy, sampled
fraction, entropy and success on held-out episodes, then check the targets:

* greedy accuracy >= 95% within 5 rounds of <= 64 episodes each,
* entropy <= 0.3 at the end,
* recall success >= 0.9 x oracle success (the oracle measured on the same held-out episodes),
* wall time of the whole run (the default run must stay within 15 minutes on 2 cores).

Usage: python scripts/bench_learning.py [--config zoo_configs/memret_ppo.yml] [--out runs/bench] [--seed 0]
"""

from __future__ import annotations

import argparse
import csv
import shutil
import time
from pathlib import Path

from sb3_memret.training.config import load_task_config
from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.evaluation.retrieval import evaluate_retrieval
from sb3_memret.policy.ppo import MemRetPPO
from sb3_memret.common.seeds import HELD_OUT_SEED
from sb3_memret.training.run import RunOptions, eval_env_kwargs, format_history, train

GREEDY_TARGET, GREEDY_ROUNDS, EPISODES_PER_ROUND = 0.95, 5, 64
ENTROPY_TARGET, SUCCESS_RATIO, WALL_MINUTES = 0.3, 0.9, 15.0


def episodes_per_round(out: Path) -> list[int]:
    with open(out / "progress.csv") as f:
        return [int(float(row["rollout/episodes"])) for row in csv.DictReader(f) if row.get("rollout/episodes")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="drawer")
    parser.add_argument("--config", type=Path, default=None, help="zoo config [default: the task's]")
    parser.add_argument("--out", type=Path, default=Path("runs/bench_learning"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eval-episodes", type=int, default=50)
    args = parser.parse_args()

    shutil.rmtree(args.out, ignore_errors=True)
    config = load_task_config(args.task, args.config)
    config.env_kwargs["task"] = args.task
    start = time.perf_counter()
    result = train(config, RunOptions(out=args.out, seed=args.seed, eval_episodes=args.eval_episodes,
                                      eval_seed=HELD_OUT_SEED, log_formats=("csv",)))
    wall = time.perf_counter() - start
    history = result.history
    print(format_history(history))

    model = MemRetPPO.load(result.model_path, device="cpu")
    venv = make_recall_vec_env(config.n_envs, eval_env_kwargs(model, result.model_path, "oracle", "scripted"))
    try:
        oracle = evaluate_retrieval(model, venv, args.eval_episodes, seed=HELD_OUT_SEED)
    finally:
        venv.close()

    final = history[-1]
    first_greedy = next((row["round"] for row in history if row["greedy_accuracy"] >= GREEDY_TARGET), None)
    episodes = episodes_per_round(args.out)
    recall_success, oracle_success = final["success"]["overall"], oracle.success["overall"]
    checks = [
        (f"greedy >= {GREEDY_TARGET:.0%} within {GREEDY_ROUNDS} rounds", first_greedy is not None and first_greedy <= GREEDY_ROUNDS,
         f"first reached at round {first_greedy}"),
        (f"<= {EPISODES_PER_ROUND} episodes per round", max(episodes, default=0) <= EPISODES_PER_ROUND,
         f"episodes per round {episodes}"),
        (f"final entropy <= {ENTROPY_TARGET}", final["entropy"] <= ENTROPY_TARGET, f"{final['entropy']:.3f}"),
        (f"recall success >= {SUCCESS_RATIO} x oracle", recall_success >= SUCCESS_RATIO * oracle_success,
         f"recall {recall_success:.0%} vs oracle {oracle_success:.0%} on {args.eval_episodes} held-out episodes"),
        (f"wall time <= {WALL_MINUTES:.0f} min", wall <= WALL_MINUTES * 60, f"{wall / 60:.1f} min, "
         f"{result.num_timesteps} decisions, {result.rounds} rounds, {config.n_envs} envs"),
    ]
    print()
    for name, ok, detail in checks:
        print(f"{'PASS' if ok else 'FAIL'}  {name}: {detail}")


if __name__ == "__main__":
    main()
