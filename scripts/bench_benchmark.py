"""Throughput of ``sb3-memret benchmark mikasa``: protocol episodes through MIKASA's harness with 1 worker
against N worker processes, in the same run, at development seeds.

    python scripts/bench_benchmark.py [--task RememberColor3-VLA-v0] [--controller scripted]
        [--condition oracle] [--episodes 8] [--workers 1 2] [--rendering] [--threads] [--overhead] [--scenes]

Each worker count plays the same ``--episodes`` episodes (seeds 5000 + i) end to end, start-up included, as a user
waits for them (``play_units``: the worker processes are spawned, build the harness env and the agent, then
play). It prints episodes/s, control steps/s and decisions/s (controller calls: one per ``replan_every`` steps)
per worker count, and each count's ratio to one worker. Each outcome is checked to be the same across counts: a
worker count changes how fast the table plays, never what it says.

With ``--rendering`` it then plays the same episodes in this process three times, rendering the cameras after every
control step (the harness's own way), only for the observations the agent reads but every camera then, and only for
those with the writer's cameras alone where nothing else reads (``sensor_gate.SensorGate``, ``Task.writer_cameras``:
the benchmark's way; it differs from the second where the condition writes facts, ``--condition written``), and
prints each one's wall and CPU seconds (lavapipe renders in this process's threads), its ratio to every-step
rendering and the outcomes, checked equal.

With ``--threads`` it plays the same episodes in this process under torch's default intra-op threads and under
one (the benchmark's own way, in one worker as in many), and prints each one's wall and CPU seconds and their
ratios: beside other jobs, idle intra-op threads spin-wait after every small op and take the cores from physics.

With ``--overhead`` it plays the same seeds in this process through the same harness env with the agent and with a
policy that returns zero actions (no memory, no controller, no writer: the harness alone), and prints each one's
control steps/s and the agent's ratio to the zero policy's: what the benchmark costs over the simulator it plays.

With ``--scenes`` it plays the same episodes in this process with the harness's env reusing its scene from one
episode to the next and with a scene built anew at every reset (``Protocol.fresh_scenes``, the benchmark's way), and
prints each one's time, its ratio to reused scenes, and each episode's return under both: fresh, none depends on the
episodes before it.
"""

from __future__ import annotations

import argparse
import math
import time

import torch

from sb3_memret.benchmark import harness
from sb3_memret.benchmark.agent import MemoryAgent
from sb3_memret.benchmark.manifest import DEV_SEED
from sb3_memret.benchmark.runner import Protocol, Unit, play_units
from sb3_memret.tasks import make_task


def play(task: str, controller: str, condition: str, episodes: int, workers: int) -> tuple[float, list[dict]]:
    """Seconds to play ``episodes`` development-seed episodes with ``workers`` workers, and their records."""
    units = [Unit(task, condition, DEV_SEED + i) for i in range(episodes)]
    protocol = Protocol(seed_set="dev", episodes=episodes, controller=controller)
    start = time.perf_counter()
    records = sorted(play_units(units, protocol, None, workers), key=lambda record: record["seed"])
    return time.perf_counter() - start, records


def play_rendering(task: str, controller: str, condition: str, episodes: int, every_step: bool,
                   writer_cameras: bool = True) -> tuple[float, float, list[tuple[bool, int]]]:
    """Wall and CPU seconds to play ``episodes`` development-seed episodes in this process (the env built
    beforehand), rendering after every step or only what the agent reads (with ``writer_cameras=False`` every camera
    whenever anything reads one), and each episode's (success, steps); one torch thread, as a benchmark worker."""
    from sb3_memret.common.workers import torch_threads
    from sb3_memret.controller_specs import make_controller

    the_task = make_task(task)
    if not writer_cameras:
        the_task.writer_cameras = None
    env = harness.make_env(task)
    try:
        agent = MemoryAgent(the_task, make_controller(controller, the_task), condition, the_task.replan_every,
                            render_every_step=every_step)
        agent.bind(env)
        outcomes, start, cpu = [], time.perf_counter(), time.process_time()
        with torch_threads(1):
            for seed in range(DEV_SEED, DEV_SEED + episodes):
                agent.begin(seed - DEV_SEED)
                result = harness.play_episode(env, agent, seed)
                outcomes.append((bool(result.success_once), int(result.n_steps)))
        return time.perf_counter() - start, time.process_time() - cpu, outcomes
    finally:
        env.close()


def play_in_process(task: str, controller: str, condition: str, episodes: int, threads: int | None = 1,
                    fresh_scenes: bool = True) -> tuple[float, float, list[dict]]:
    """Wall and CPU seconds (this process's, its threads included) to play ``episodes`` development-seed episodes in
    this process, as one benchmark worker does, with ``threads`` torch intra-op threads (None: torch's default) and
    fresh or reused scenes, the env and the agent built beforehand; and each episode's record."""
    from sb3_memret.benchmark.runner import _Worker
    from sb3_memret.common.workers import torch_threads

    worker = _Worker(Protocol(seed_set="dev", episodes=episodes, controller=controller, fresh_scenes=fresh_scenes),
                     None)
    worker.agent(task, condition)
    try:
        with torch_threads(threads):
            start, cpu = time.perf_counter(), time.process_time()
            records = [worker.play(Unit(task, condition, DEV_SEED + i)) for i in range(episodes)]
            return time.perf_counter() - start, time.process_time() - cpu, records
    finally:
        worker.env.close()


class ZeroPolicy:
    """The harness alone: a ``ChunkPolicy`` of zero actions, ``chunk_size`` at a call."""

    def __init__(self, chunk_size: int, action_dim: int = 7):
        self.chunk_size, self.action_dim = chunk_size, action_dim

    def forward(self, obs: object) -> torch.Tensor:
        return torch.zeros(self.chunk_size, self.action_dim)


def play_overhead(task: str, controller: str, condition: str, episodes: int) -> list[tuple[str, float, int]]:
    """(policy, seconds, control steps) of ``episodes`` development-seed episodes through one harness env, played by
    the agent and by ``ZeroPolicy`` (its replan interval's chunks)."""
    from sb3_memret.controller_specs import make_controller

    the_task = make_task(task)
    env = harness.make_env(task)
    try:
        agent = MemoryAgent(the_task, make_controller(controller, the_task), condition, the_task.replan_every)
        agent.bind(env)
        out = []
        for name, policy in (("the agent", agent), ("zero actions (the harness alone)", ZeroPolicy(agent.chunk_size))):
            steps, start = 0, time.perf_counter()
            for seed in range(DEV_SEED, DEV_SEED + episodes):
                if policy is agent:
                    agent.begin(seed - DEV_SEED)
                steps += int(harness.play_episode(env, policy, seed).n_steps)
            out.append((name, time.perf_counter() - start, steps))
        return out
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="RememberColor3-VLA-v0")
    parser.add_argument("--controller", default="scripted")
    parser.add_argument("--condition", default="oracle", choices=["none", "oracle", "wrong", "written"])
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--rendering", action="store_true", help="also compare every-step rendering with the gate")
    parser.add_argument("--threads", action="store_true", help="also compare torch's default threads with one")
    parser.add_argument("--overhead", action="store_true", help="also compare the agent with zero actions")
    parser.add_argument("--scenes", action="store_true", help="also compare reused scenes with fresh ones")
    args = parser.parse_args()

    replan_every = make_task(args.task).replan_every
    print(f"{args.task}, {args.controller} controller, {args.condition}, {args.episodes} episodes at seeds "
          f"{DEV_SEED}..{DEV_SEED + args.episodes - 1}, replanning every {replan_every} steps")
    print("| workers | seconds | episodes/s | steps/s | decisions/s | vs 1 worker | success |")
    print("|---|---|---|---|---|---|---|")
    base, outcomes = None, None
    for workers in args.workers:
        seconds, records = play(args.task, args.controller, args.condition, args.episodes, workers)
        errors = [record["error"] for record in records if "error" in record]
        if errors:
            raise SystemExit(f"{len(errors)} episodes failed with {workers} workers: {errors[0]}")
        steps = sum(record["steps"] for record in records)
        decisions = sum(math.ceil(record["steps"] / replan_every) for record in records)
        outcome = [(record["success"], record["steps"]) for record in records]
        if outcomes is not None and outcome != outcomes:
            raise SystemExit(f"{workers} workers played other outcomes than {args.workers[0]}: {outcome} vs {outcomes}")
        outcomes, rate = outcome, args.episodes / seconds
        base = base or rate
        print(f"| {workers} | {seconds:.1f} | {rate:.3f} | {steps / seconds:.1f} | {decisions / seconds:.2f} | "
              f"{rate / base:.2f}x | {sum(s for s, _ in outcome)}/{args.episodes} |")
    if args.rendering:
        print("\n| rendering (1 process) | seconds | CPU seconds | steps/s | vs every step, wall | vs every step, CPU "
              "| success |")
        print("|---|---|---|---|---|---|---|")
        ways = {"every step (the harness's)": (True, True), "what the agent reads, every camera": (False, False),
                "what the agent reads, the writer's cameras alone": (False, True)}
        played = {name: play_rendering(args.task, args.controller, args.condition, args.episodes, *way)
                  for name, way in ways.items()}
        every, every_cpu, every_outcomes = next(iter(played.values()))
        for name, (seconds, cpu, outcomes) in played.items():
            if outcomes != every_outcomes:
                raise SystemExit(f"rendering {name} changed the outcomes: {outcomes} vs {every_outcomes}")
            steps = sum(n for _, n in outcomes)
            print(f"| {name} | {seconds:.1f} | {cpu:.1f} | {steps / seconds:.1f} | {every / seconds:.2f}x | "
                  f"{every_cpu / cpu:.2f}x | {sum(s for s, _ in outcomes)}/{args.episodes} |")

    if args.threads:
        print("\n| torch threads (1 process) | seconds | CPU seconds | vs default, wall | vs default, CPU | success |")
        print("|---|---|---|---|---|---|")
        played = {}
        for threads in (None, 1):
            seconds, cpu, records = play_in_process(args.task, args.controller, args.condition, args.episodes, threads)
            played[threads] = seconds, cpu, [(record["success"], record["steps"]) for record in records]
        if played[1][2] != played[None][2]:
            raise SystemExit(f"one thread played other outcomes: {played[1][2]} vs {played[None][2]}")
        (wall, cpu, outcomes) = played[None]
        for threads, (seconds, cpu_seconds, _) in played.items():
            name = f"default ({torch.get_num_threads()})" if threads is None else "one (the benchmark's)"
            print(f"| {name} | {seconds:.1f} | {cpu_seconds:.1f} | {wall / seconds:.2f}x | {cpu / cpu_seconds:.2f}x | "
                  f"{sum(s for s, _ in outcomes)}/{args.episodes} |")

    if args.overhead:
        print("\n| policy (1 process, the same harness env) | seconds | control steps | steps/s | vs zero actions |")
        print("|---|---|---|---|---|")
        played = play_overhead(args.task, args.controller, args.condition, args.episodes)
        zero_rate = played[-1][2] / played[-1][1]
        for name, seconds, steps in played:
            print(f"| {name} | {seconds:.1f} | {steps} | {steps / seconds:.1f} | {steps / seconds / zero_rate:.2f}x |")

    if args.scenes:
        print("\n| scenes (1 process) | seconds | episodes/s | vs reused | success | returns |")
        print("|---|---|---|---|---|---|")
        reused = None
        for name, fresh in (("reused (the harness's env)", False), ("fresh at every reset (the benchmark's)", True)):
            seconds, _, records = play_in_process(args.task, args.controller, args.condition, args.episodes,
                                                  fresh_scenes=fresh)
            reused = reused or seconds
            returns = ", ".join(f"{record['return']:.5f}" for record in records)
            print(f"| {name} | {seconds:.1f} | {args.episodes / seconds:.3f} | {reused / seconds:.2f}x | "
                  f"{sum(record['success'] for record in records)}/{args.episodes} | {returns} |")


if __name__ == "__main__":
    main()
