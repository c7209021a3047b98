"""Decision throughput of RecallVecEnv (one controller in the trainer, physics in workers) against
SB3's SubprocVecEnv over DrawerRecall-v0 (a controller in every worker), measured in the same run.

Every configuration is built and warmed up first (``--warmup`` rounds, so start-up is left out),
then they take turns: ``--windows`` windows of ``--rounds`` decision rounds each, interleaved so
that a shared machine's slow drifts hit every path alike (episode resets inside windows count;
slot picks are uniformly random). It reports the median window, the range, and the CPU time
(trainer and its workers) per decision, which the time a shared host steals does not inflate:

- decisions/s of the one-controller VecEnv on N worker processes, and the ratio to N = 1;
- decisions/s of the per-worker-controller SubprocVecEnv at the same N (the path it replaces);
- the controller's time per call and its share of the trainer's wall time;
- with ``--ray``, the same VecEnv on N local Ray actors.

Usage: ``python scripts/bench_vec_env.py [--task drawer] [--controller learned-state] [--n-envs 1 2 4]
[--rounds 40] [--ray] [--render-backend cpu|gpu]`` (a camera controller needs a render backend; the
SubprocVecEnv baseline, DrawerRecall-v0, runs on the drawer only). ``--task RememberColor3-VLA-v0 --controller
learned --render-backend cpu`` measures camera ``train recall`` on a MIKASA task.
It also times the controller alone at batch 1 and batch N on recorded observations.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import gymnasium as gym
import numpy as np
import psutil
from stable_baselines3.common.vec_env import SubprocVecEnv, VecEnv

from sb3_memret.controller_specs import make_controller
from sb3_memret.envs import RECALL_ENV_ID
from sb3_memret.common.obs_trees import stack_obs, to_numpy
from sb3_memret.envs.vec_env import recall_vec_env
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.evaluation.rollout import task_env_kwargs
from sb3_memret.tasks import DEFAULT_TASK, make_task
from sb3_memret.tasks.base import RENDER_BACKENDS
from sb3_memret.common.workers import init_worker_process

SEED = 1_000_000


def _recall_env(controller: str, render_backend: str) -> Callable[[], gym.Env]:
    def make() -> gym.Env:
        import sb3_memret.tasks.drawer.drawer_cube  # noqa: F401  (registers DrawerCubeTakeOut-v1)

        init_worker_process()
        return gym.make(RECALL_ENV_ID, controller=controller, render_backend=render_backend)

    return make


@dataclass
class Config:
    """A configuration under test: its VecEnv, its timed controller (one-controller paths), its windows."""

    venv: VecEnv
    workers: list[int]  # pids of the processes that run its physics
    timed: "TimedController | None" = None
    rates: list[float] = field(default_factory=list)
    seconds: float = 0.0
    cpu_seconds: float = 0.0  # trainer + workers: immune to the time a shared host steals
    decisions: int = 0
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))

    def step(self) -> None:
        n, capacity = self.venv.num_envs, int(self.venv.action_space.nvec[0])
        self.venv.step(self.rng.integers(capacity, size=(n, 1)))

    def start(self, warmup: int) -> None:
        self.venv.seed(SEED)
        self.venv.reset()
        for _ in range(warmup):
            self.step()
        if self.timed is not None:
            self.timed.reset_counts()

    def cpu_time(self) -> float:
        processes = [psutil.Process(), *map(psutil.Process, self.workers)]
        return sum(p.cpu_times().user + p.cpu_times().system for p in processes)

    def window(self, rounds: int) -> None:
        cpu, start = self.cpu_time(), time.perf_counter()
        for _ in range(rounds):
            self.step()
        seconds = time.perf_counter() - start
        self.cpu_seconds += self.cpu_time() - cpu
        self.decisions += self.venv.num_envs * rounds
        self.rates.append(self.venv.num_envs * rounds / seconds)
        self.seconds += seconds


class TimedController:
    """Wraps a controller's ``act`` to add up the time spent in it."""

    def __init__(self, controller: Any):
        self.controller, self.seconds, self.calls = controller, 0.0, 0
        self._act = controller.act
        controller.act = self.act

    def act(self, *args: Any, **kwargs: Any) -> np.ndarray:
        start = time.perf_counter()
        try:
            return self._act(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - start
            self.calls += 1

    def reset_counts(self) -> None:
        self.seconds, self.calls = 0.0, 0


def one_controller(controller: str, n: int, backend: str, render_backend: str, task: str = DEFAULT_TASK) -> Config:
    timed = TimedController(make_controller(controller, task))
    venv = recall_vec_env(n, task=task, controller=timed.controller, backend=backend, render_backend=render_backend)
    physics = venv.physics
    pids = physics.pids() if backend == "ray" else [p.pid for p in physics.processes]
    return Config(venv, pids, timed)


def per_worker_controllers(controller: str, n: int, render_backend: str) -> Config:
    venv = SubprocVecEnv([_recall_env(controller, render_backend) for _ in range(n)], start_method="spawn")
    return Config(venv, [p.pid for p in venv.processes])


def controller_alone(controller: str, batch: int, render_backend: str, task_name: str = DEFAULT_TASK,
                     calls: int = 30) -> float:
    """Milliseconds per ``act`` call at ``batch`` envs, on the observation of a real episode's start with its
    oracle prompt."""
    task = make_task(task_name)
    ctrl = make_controller(controller, task)
    env = task.make_env(**task_env_kwargs(ctrl, render_backend, task))
    obs, info = env.reset(seed=SEED)
    frame, = task.frames(env, obs, info, reset=True)
    env.close()
    batched = stack_obs([to_numpy(frame.obs)] * batch)
    episode = task.episode(frame)
    prompts = [build_prompt(task.instruction(episode), task.oracle_facts(episode), ctrl.spec.prompt_template)] * batch
    ctrl.reset(list(range(batch)))
    ctrl.act(batched, prompts)
    start = time.perf_counter()
    for _ in range(calls):
        ctrl.act(batched, prompts)
    return 1e3 * (time.perf_counter() - start) / calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default=DEFAULT_TASK)
    parser.add_argument("--controller", default="learned-state")
    parser.add_argument("--n-envs", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--rounds", type=int, default=25, help="decision rounds per measured window")
    parser.add_argument("--windows", type=int, default=5, help="measured windows per configuration")
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--ray", action="store_true", help="also run the physics as local Ray actors")
    parser.add_argument("--skip-baseline", action="store_true", help="leave out the SubprocVecEnv baseline")
    parser.add_argument("--render-backend", choices=RENDER_BACKENDS, default="none",
                        help="SAPIEN render backend: cpu or gpu for a controller that reads cameras")
    args = parser.parse_args()
    baseline = not args.skip_baseline and args.task == DEFAULT_TASK  # DrawerRecall-v0 is the drawer's
    print(f"{os.cpu_count()} CPU cores, task {args.task}, controller {args.controller}, render backend "
          f"{args.render_backend}, "
          f"{args.rounds} rounds after {args.warmup}\n")

    print("| envs | batch-1 act ms | batch-N act ms |")
    print("|---|---|---|")
    one = controller_alone(args.controller, 1, args.render_backend, args.task)
    for n in args.n_envs:
        print(f"| {n} | {one:.2f} | {controller_alone(args.controller, n, args.render_backend, args.task):.2f} |")

    if args.ray:
        import logging

        import ray

        ray.init(include_dashboard=False, logging_level=logging.WARNING)
    configs: dict[tuple[str, int], Config] = {}
    try:
        for n in args.n_envs:
            configs[("process", n)] = one_controller(args.controller, n, "process", args.render_backend, args.task)
            if baseline:
                configs[("subproc", n)] = per_worker_controllers(args.controller, n, args.render_backend)
            if args.ray and n > 1:
                configs[("ray", n)] = one_controller(args.controller, n, "ray", args.render_backend, args.task)
        for config in configs.values():
            config.start(args.warmup)
        for _ in range(args.windows):  # interleaved, so slow drifts of a shared machine hit every path alike
            for config in configs.values():
                config.window(args.rounds)
    finally:
        for config in configs.values():
            config.venv.close()
    rate = {key: float(np.median(c.rates)) for key, c in configs.items()}
    base = rate[("process", min(args.n_envs))]
    print(f"\n| path | envs | decisions/s (median of {args.windows}) | range | vs {min(args.n_envs)} worker (one "
          "controller) | vs SubprocVecEnv, same N | CPU ms/decision | controller ms/call | controller share |")
    print("|---|---|---|---|---|---|---|---|---|")
    names = {"process": "one controller, worker processes", "subproc": "SubprocVecEnv, controller per worker",
             "ray": "one controller, Ray actors"}
    for (path, n), config in configs.items():
        subproc = rate.get(("subproc", n))
        versus = f"{rate[path, n] / subproc:.2f}x" if subproc and path != "subproc" else "-"
        timed = config.timed
        timing = (f"{1e3 * timed.seconds / timed.calls:.1f} | {timed.seconds / config.seconds:.0%}" if timed
                  else "- | -")
        spread = f"{min(config.rates):.1f}-{max(config.rates):.1f}"
        cpu = 1e3 * config.cpu_seconds / config.decisions
        print(f"| {names[path]} | {n} | {rate[path, n]:.1f} | {spread} | {rate[path, n] / base:.2f}x | {versus} | "
              f"{cpu:.0f} | {timing} |")


if __name__ == "__main__":
    main()
