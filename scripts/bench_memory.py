"""Time the memory layer per decision step against one controller chunk, in the same run.

A decision step is: read the simulator into predicates, compile changes into entries,
encode them (MiniLM, cached by text), write them into the bank, age it and take the policy's
array view. The controller chunk is the scripted controller's ``act`` plus the 8 env steps it
drives. Episode 0 starts with an empty text cache (cold); the rest reuse it (warm).
Usage: ``python scripts/bench_memory.py [--episodes N]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
from sb3_memret.memory.bank import MemoryBank
from sb3_memret.memory.encoder import MiniLMEncoder
from sb3_memret.memory.writer import EventCompiler
from sb3_memret.tasks.drawer.seeding import seed_memories
from sb3_memret.tasks.drawer.writer import RELATIONS, BoundingBoxPredicateExtractor
from sb3_memret.tasks.drawer.prompts import condition_prompt

REPLAN_EVERY = 8


def run(episodes: int) -> list[tuple[float, float]]:
    """(memory seconds, control seconds) for every decision step of every episode."""
    env, controller = DrawerTask().make_env(), ScriptedDrawerController()
    encoder = MiniLMEncoder()
    extractor, compiler, bank = BoundingBoxPredicateExtractor(), EventCompiler(encoder, RELATIONS, DrawerTask.wordings), MemoryBank(6)
    timings = []
    for episode in range(episodes):
        layer = episode % 3 + 1
        obs, _ = env.reset(seed=episode, options={"target_layer": layer})
        controller.reset([episode])
        compiler.reset()
        bank.clear()
        rng = np.random.default_rng(episode)
        seeds = seed_memories({"cube": layer}, "cube", rng)
        for entry, vector in zip(seeds, encoder.encode([e.text for e in seeds])):
            bank.write(entry.with_embedding(vector))
        prompt, t, done = condition_prompt("oracle", layer), 0, False
        while not done:
            start = time.perf_counter()
            for entry in compiler.update(extractor.extract(env.unwrapped.privileged_state()), t):
                bank.write(entry)
            bank.age(t)
            bank.view()
            mid = time.perf_counter()
            for action in controller.act(obs, [prompt])[0][:REPLAN_EVERY]:
                obs, _, terminated, truncated, _ = env.step(action)
                t += 1
                done = bool(terminated) or bool(truncated)
                if done:
                    break
            timings.append((episode, mid - start, time.perf_counter() - mid))
    return timings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=6)
    args = parser.parse_args()
    timings = np.array(run(args.episodes))
    print(f"{len(timings)} decision steps over {args.episodes} episodes (scripted controller, replan every {REPLAN_EVERY})")
    for name, rows in (("cold cache (episode 0)", timings[timings[:, 0] == 0]),
                       ("warm cache", timings[timings[:, 0] > 0]), ("all", timings)):
        if len(rows) == 0:
            continue
        memory, control = rows[:, 1].mean() * 1e3, rows[:, 2].mean() * 1e3
        print(f"{name:24s} memory {memory:7.3f} ms | controller chunk {control:7.2f} ms | "
              f"memory share of a decision step {memory / (memory + control):6.2%} (target <= 5%)")


if __name__ == "__main__":
    main()
