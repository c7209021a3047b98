"""Decision throughput of RecallVecEnv on the batched GPU simulation (``--backend gpu``: one ManiSkill env
with ``num_envs=N`` and ``sim_backend="gpu"``, ``BatchedSimPhysics``), ONE controller call per decision round.

Every (controller, N) is built, warmed up (``--warmup`` rounds: start-up and first kernel launches left out),
timed over ``--windows`` windows of ``--rounds`` decision rounds with uniformly random slot picks (episode
resets inside windows count), and closed before the next is built. It reports the median window's
decisions/s and rounds/s, the range, the ratio to the smallest N of the same controller in the same run,
and the controller's and the physics' time per round.

It also times the controller alone at ``--batches`` on real observations (``--controller-device``), and
checks that the batched physics is not silently wrong: the scripted controller in oracle mode at
``--check-envs`` envs plays every env's first episode, and the success rate is printed (near 100% on the
CPU physics).

``--sim-backend cpu`` runs the same path on ManiSkill's CPU simulation, which holds one env: a dry run at
N = 1 on a machine without a GPU.

Usage: ``python scripts/bench_gpu_physics.py [--n-envs 1 16 64 256] [--controller scripted learned-state learned]
[--controller-device cuda] [--sim-backend cpu]``.
"""

from __future__ import annotations

import argparse
import gc
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from sb3_memret.controllers import FrozenController
from sb3_memret.controller_specs import make_controller
from sb3_memret.controllers.learned import LearnedController, default_checkpoint
from sb3_memret.common.obs_trees import stack_obs, to_numpy
from sb3_memret.envs.vec_env import RecallVecEnv, make_recall_vec_env
from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer.prompts import condition_prompt
from sb3_memret.evaluation.rollout import task_env_kwargs

SEED = 1_000_000


class Timer:
    """Adds up the wall time of the calls to one method of an object, wrapping it in place."""

    def __init__(self, owner: Any, name: str):
        self.seconds, self.calls = 0.0, 0
        self._method = getattr(owner, name)
        setattr(owner, name, self)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return self._method(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - start
            self.calls += 1

    def reset_counts(self) -> None:
        self.seconds, self.calls = 0.0, 0

    def ms_per_call(self) -> float:
        return 1e3 * self.seconds / max(self.calls, 1)


@dataclass
class Result:
    """One (controller, N) measured: its windows' decisions/s and where a round's time went."""

    rates: list[float] = field(default_factory=list)
    controller_ms: float = 0.0
    physics_ms: float = 0.0


def build_controller(name: str, device: str) -> FrozenController:
    """The controller ``name`` names; the drawer's shipped learned checkpoints run on ``device``."""
    if name in ("learned", "learned-state"):
        return LearnedController(default_checkpoint(name), DrawerTask(), device=device)
    return make_controller(name, DrawerTask())


def batched_venv(n: int, controller: FrozenController, sim_backend: str, mode: str = "recall") -> RecallVecEnv:
    """``make_recall_vec_env(n, backend="gpu")`` with its physics on ``sim_backend``, unwrapped from its VecMonitor."""
    kwargs = {"controller": controller, "mode": mode, "task_kwargs": {"sim_backend": sim_backend},
              "render_backend": "gpu" if controller.spec.needs_images else "none"}  # a camera controller renders there
    return make_recall_vec_env(n, kwargs, seed=SEED, backend="gpu").unwrapped


def release_gpu() -> None:
    """Frees what a closed env left behind before the next one is built."""
    gc.collect()
    if torch.cuda.is_available():
        torch.cuda.empty_cache()


def random_round(venv: RecallVecEnv, rng: np.random.Generator) -> tuple[np.ndarray, list[dict]]:
    """One decision round with uniformly random slot picks; the dones and infos."""
    venv.step_async(rng.integers(venv.slots, size=(venv.num_envs, venv.k)))
    _, _, dones, infos = venv.step_wait()
    return dones, infos


def measure(name: str, n: int, args: argparse.Namespace) -> Result:
    """Decision throughput of one (controller, N), built, warmed up, timed and closed here."""
    venv = batched_venv(n, build_controller(name, args.controller_device), args.sim_backend)
    act, execute = Timer(venv.controller, "act"), Timer(venv.physics, "execute")
    rng = np.random.default_rng(0)
    result = Result()
    try:
        venv.reset()
        for _ in range(args.warmup):
            random_round(venv, rng)
        act.reset_counts()
        execute.reset_counts()
        for _ in range(args.windows):
            start = time.perf_counter()
            for _ in range(args.rounds):
                random_round(venv, rng)
            result.rates.append(n * args.rounds / (time.perf_counter() - start))
    finally:
        venv.close()
        release_gpu()
    result.controller_ms, result.physics_ms = act.ms_per_call(), execute.ms_per_call()
    return result


def oracle_success(n: int, args: argparse.Namespace) -> tuple[int, int, dict[int, tuple[int, int]]]:
    """The scripted controller in oracle mode at ``n`` envs, every env's first episode: successes, episodes,
    and (successes, episodes) per cube layer."""
    venv = batched_venv(n, build_controller("scripted", "cpu"), args.sim_backend, mode="oracle")
    rng = np.random.default_rng(0)
    outcome: dict[int, tuple[bool, int]] = {}
    try:
        venv.reset()
        layers = [memory.layer for memory in venv.memories]
        while len(outcome) < n:
            dones, infos = random_round(venv, rng)
            for i in np.flatnonzero(dones):
                outcome.setdefault(int(i), (bool(infos[i]["success"]), layers[i]))
            layers = [memory.layer for memory in venv.memories]
    finally:
        venv.close()
        release_gpu()
    per_layer: dict[int, tuple[int, int]] = {}
    for success, layer in outcome.values():
        wins, total = per_layer.get(layer, (0, 0))
        per_layer[layer] = (wins + success, total + 1)
    return sum(success for success, _ in outcome.values()), n, dict(sorted(per_layer.items()))


def controller_alone(name: str, device: str, batches: list[int], calls: int) -> dict[int, float]:
    """Milliseconds per ``act`` call at each batch size, on an observation of a real episode start."""
    ctrl = build_controller(name, device)
    env = DrawerTask().make_env(**task_env_kwargs(ctrl, "none", DrawerTask()))
    obs, _ = env.reset(seed=SEED)
    frame = to_numpy(obs)
    env.close()
    times = {}
    for batch in batches:
        batched = stack_obs([frame] * batch)
        prompts = [condition_prompt("oracle", 1 + i % 3) for i in range(batch)]
        ctrl.reset(list(range(batch)))
        for _ in range(3):
            ctrl.act(batched, prompts)
        start = time.perf_counter()
        for _ in range(calls):
            ctrl.act(batched, prompts)
        times[batch] = 1e3 * (time.perf_counter() - start) / calls
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controller", nargs="+", default=["scripted", "learned-state"])
    parser.add_argument("--controller-device", default="cuda" if torch.cuda.is_available() else "cpu",
                        help="where the learned controller computes")
    parser.add_argument("--n-envs", type=int, nargs="+", default=[1, 16, 64, 256])
    parser.add_argument("--sim-backend", default="gpu", choices=["gpu", "cpu"],
                        help="cpu: ManiSkill's CPU simulation, N = 1 only (a dry run without a GPU)")
    parser.add_argument("--rounds", type=int, default=20, help="decision rounds per measured window")
    parser.add_argument("--windows", type=int, default=3, help="measured windows per (controller, N)")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 16, 64, 256],
                        help="batch sizes of the controller timed alone")
    parser.add_argument("--calls", type=int, default=30, help="timed act calls per batch size")
    parser.add_argument("--check-envs", type=int, default=16, help="envs of the oracle success check (0: skip)")
    args = parser.parse_args()
    if args.sim_backend == "cpu" and (max(args.n_envs) > 1 or args.check_envs > 1):
        parser.error("ManiSkill's CPU simulation holds one env: use --n-envs 1 --check-envs 1 (or 0)")
    device = torch.cuda.get_device_name() if torch.cuda.is_available() else "no CUDA device"
    print(f"{device}; physics {args.sim_backend}, controller on {args.controller_device}; {args.windows} windows "
          f"of {args.rounds} rounds after {args.warmup}\n", flush=True)

    print("| controller | batch | act ms/call |")
    print("|---|---|---|")
    for name in args.controller:
        for batch, ms in controller_alone(name, args.controller_device, args.batches, args.calls).items():
            print(f"| {name} | {batch} | {ms:.2f} |", flush=True)

    if args.check_envs:
        wins, episodes, per_layer = oracle_success(args.check_envs, args)
        layers = ", ".join(f"layer {layer}: {w}/{t}" for layer, (w, t) in per_layer.items())
        print(f"\noracle success, scripted, {episodes} envs' first episodes: {wins}/{episodes} = "
              f"{wins / episodes:.0%} ({layers})", flush=True)

    print(f"\n| controller | envs | decisions/s (median of {args.windows}) | range | rounds/s | vs smallest N | "
          "controller ms/round | physics ms/round |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.controller:
        base = None
        for n in sorted(args.n_envs):
            result = measure(name, n, args)
            rate = float(np.median(result.rates))
            base = base or rate
            print(f"| {name} | {n} | {rate:.1f} | {min(result.rates):.1f}-{max(result.rates):.1f} | {rate / n:.2f} | "
                  f"{rate / base:.2f}x | {result.controller_ms:.1f} | {result.physics_ms:.1f} |", flush=True)


if __name__ == "__main__":
    main()
