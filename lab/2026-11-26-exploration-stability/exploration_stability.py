"""Does the memory learner keep what it learns? Held-out greedy retrieval after each round of decisions, per seed,
for each Plackett-Luce exploration kind, on the test suite's K = 2 toy task (PairDoors: two facts and two decoys,
the scripted controller needs both in its prompt; seconds a round).

Usage: python lab/2026-11-26-exploration-stability/exploration_stability.py [--seeds 0 1 2 3] [--rounds 3] [--learning-rate 3e-4] [--ent-coef 0.001]
Prints one line per exploration kind and seed: greedy accuracy after each round of 1024 decisions, and a summary
(seeds that reached >= 0.9, and of those, how many fell back below it later).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))

from test_tasks import pair_doors_env  # noqa: E402  (the toy task lives with the tests that define it)

from sb3_memret.evaluation.retrieval import evaluate_retrieval  # noqa: E402
from sb3_memret.memory.encoder import MiniLMEncoder  # noqa: E402
from sb3_memret.policy.policy import EXPLORATION  # noqa: E402
from sb3_memret.policy.ppo import MemRetPPO  # noqa: E402


def greedy_by_round(exploration: str, seed: int, rounds: int, decisions: int, encoder: MiniLMEncoder,
                    learning_rate: float, ent_coef: float) -> list[float]:
    """Train from scratch and evaluate greedy retrieval on 20 held-out episodes after each round."""
    venv = pair_doors_env(encoder)
    model = MemRetPPO(env=venv, n_steps=64, batch_size=32, gae_lambda=0.7, learning_rate=learning_rate,
                      ent_coef=ent_coef, seed=seed, policy_kwargs={"exploration": exploration})
    accuracy = []
    for _ in range(rounds):
        model.learn(decisions, reset_num_timesteps=False)
        accuracy.append(evaluate_retrieval(model, venv, 20, seed=1000).greedy_accuracy)
    venv.close()
    return accuracy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--decisions", type=int, default=1024, help="decisions between evaluations")
    parser.add_argument("--learning-rate", type=float, default=3e-4)
    parser.add_argument("--ent-coef", type=float, default=0.001)
    parser.add_argument("--exploration", nargs="+", default=list(EXPLORATION), choices=EXPLORATION)
    args = parser.parse_args()
    encoder = MiniLMEncoder()
    for exploration in args.exploration:
        reached = fell = 0
        for seed in args.seeds:
            acc = greedy_by_round(exploration, seed, args.rounds, args.decisions, encoder, args.learning_rate,
                                  args.ent_coef)
            first = next((i for i, a in enumerate(acc) if a >= 0.9), None)
            reached += first is not None
            fell += first is not None and any(a < 0.9 for a in acc[first:])
            print(f"{exploration:8s} seed {seed}: greedy " + " ".join(f"{a:.2f}" for a in acc), flush=True)
        print(f"{exploration:8s} reached 0.9 on {reached} of {len(args.seeds)} seeds; fell back below it on {fell}\n",
              flush=True)


if __name__ == "__main__":
    main()
