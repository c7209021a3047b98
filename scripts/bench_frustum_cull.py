"""Control steps of a MIKASA harness env with every body drawn against each camera drawing only what it can see
(``sb3_memret.physics.frustum_cull``), in the same run, and a check that every picture is the same bit for bit.

    python scripts/bench_frustum_cull.py [--tasks RememberColor9-VLA-v0 InterceptSlow-VLA-v0] [--steps 12]
        [--seeds 5000 5001]

The harness env renders both 128x128 cameras into every step's observation. For each task and development seed it
plays the same ``--steps`` fixed sweeping actions twice from the same reset (the scene built anew, as the benchmark
plays), once with ManiSkill's capture and once culled, alternating which goes first, and prints CPU milliseconds per
step, the reset's share included (lavapipe draws in this process's threads; a picture's work finishes
asynchronously, so whole episodes are timed, not single renders), their ratio, and the bodies the wrist camera
skipped.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from sb3_memret.benchmark import harness
from sb3_memret.benchmark.manifest import DEV_SEED
from sb3_memret.physics.frustum_cull import FrustumCull


def play(env, seed: int, steps: int) -> tuple[list[np.ndarray], float]:
    """Every step's pictures from ``seed``'s reset under fixed actions, and the CPU seconds of the reset (a scene
    built anew, its pictures taken) and the steps, per step."""
    start = time.process_time()
    env.reset(seed=seed)
    pictures = []
    for step in range(steps):
        action = np.random.default_rng(step).uniform(-0.6, 0.6, env.action_space.shape).astype(np.float32)
        obs, *_ = env.step(action)
        pictures.append(np.asarray(obs["rgb"]).copy())  # the harness's both cameras
    return pictures, (time.process_time() - start) / steps


def wrist_skips(base, cull: FrustumCull) -> list[str]:
    """The bodies the wrist camera skipped at the step just rendered."""
    hand = base._sensors["hand_camera"].camera._render_cameras[0]
    bodies = list(base.scene.sub_scenes[0].render_system.render_bodies)
    return [body.entity.name for body in cull.hidden(hand, bodies, cull._blind.get("hand_camera", []))]


def measure(task: str, seeds: list[int], steps: int) -> dict[str, float]:
    """CPU milliseconds per control step with ManiSkill's capture and with the culled one, mean over ``seeds``."""
    env = harness.make_env(task, fresh_scenes=True)
    base = env.unwrapped
    ways = {"full": base.capture_sensor_data, "culled": FrustumCull(base).capture}
    seconds = {way: 0.0 for way in ways}
    try:
        play(env, seeds[0], 2)  # warm-up: shaders compiled
        for i, seed in enumerate(seeds):
            pictures = {}
            for way in (("full", "culled") if i % 2 == 0 else ("culled", "full")):
                base.capture_sensor_data = ways[way]
                pictures[way], took = play(env, seed, steps)
                seconds[way] += took
                if way == "culled":
                    skipped = wrist_skips(base, ways[way].__self__)
            for step, (full, culled) in enumerate(zip(pictures["full"], pictures["culled"])):
                if not np.array_equal(full, culled):
                    raise AssertionError(f"{task} seed {seed} step {step}: the culled pictures differ")
        print(f"{task}: the wrist camera skipped {skipped} at the last culled step")
    finally:
        base.capture_sensor_data = ways["full"]
        env.close()
    return {way: s / len(seeds) * 1000 for way, s in seconds.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=["RememberColor9-VLA-v0", "InterceptSlow-VLA-v0"])
    parser.add_argument("--steps", type=int, default=12)
    parser.add_argument("--seeds", type=int, nargs="+", default=[DEV_SEED + i for i in range(4)])
    args = parser.parse_args()
    rows = {task: measure(task, args.seeds, args.steps) for task in args.tasks}
    print(f"\nCPU ms per control step, both cameras rendered (128x128), the reset's share included, {args.steps} steps "
          f"at each of seeds {args.seeds}; every picture the same bit for bit")
    print("| task | every body drawn | each camera's view only | speed-up |")
    print("|---|---|---|---|")
    for task, ms in rows.items():
        print(f"| {task} | {ms['full']:.1f} | {ms['culled']:.1f} | {ms['full'] / ms['culled']:.2f}x |")


if __name__ == "__main__":
    main()
