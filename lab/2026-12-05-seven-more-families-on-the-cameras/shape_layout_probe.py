"""Where the base camera places RememberShape's (and RememberShapeAndColor's) objects at the choice, against the
FindImposter task's shipped exemplars of the same objects: each development seed's first frame the reader reads
(zero actions), the objects named and each one's error in centimetres against the simulator. ``--reader imposter``:
FindImposter's (``imposter_places``: only a frame that shows all N apart); ``--reader remember``: the shipped one
(``remember_places``: any frame with more than the cue's one object, touching objects cut apart).

    .venv/bin/python lab/2026-12-05-seven-more-families-on-the-cameras/shape_layout_probe.py \
        --task RememberShape9-VLA-v0 --reader remember --seeds 20
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_memret.controllers.base import as_numpy
from sb3_memret.tasks import make_task
from sb3_memret.tasks.mikasa.find_imposter.camera_expert import imposter_places
from sb3_memret.tasks.mikasa.find_imposter.perception import task_exemplars
from sb3_memret.tasks.mikasa.remember.shape_camera_expert import candidates, shape_places


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="RememberShape5-VLA-v0")
    parser.add_argument("--reader", choices=("imposter", "remember"), default="remember")
    parser.add_argument("--seeds", type=int, default=10, help="development seeds 5000 + i")
    parser.add_argument("--steps", type=int, default=25)
    args = parser.parse_args()
    task = make_task(args.task)
    words = list(task.words)
    if args.reader == "remember":
        read = shape_places(args.task, words)
    else:
        imposter = args.task.replace("Remember", "FindImposter").replace("-Long", "")  # the same objects
        read = imposter_places(words, candidates(args.task, words), task_exemplars(imposter))
    env = task.make_env(obs_mode="rgb")
    worst, placed_all, wrong = 0.0, 0, 0  # wrong: objects placed over 3 cm off (named for another)
    for seed in range(5000, 5000 + args.seeds):
        obs, _ = env.reset(seed=seed)
        places = {}
        for step in range(args.steps):
            places = read(obs["sensor_data"]["base_camera"]["rgb"])
            if len(places) == len(words):
                break
            obs, *_ = env.step(np.zeros(env.action_space.shape))
        base = env.unwrapped
        actors = [base.shape_actors[i] for i in sorted(base.shape_actors)]
        truth = {words[i]: as_numpy(a.pose.p).reshape(-1)[:2] for i, a in enumerate(actors)}
        errors = {w: round(100 * float(np.linalg.norm(p - truth[w])), 2) for w, p in places.items()}
        placed_all += len(places) == len(words)
        wrong += sum(e > 3 for e in errors.values())
        worst = max([worst, *(e for e in errors.values() if e <= 3)])
        print(f"seed {seed} step {step}: placed {len(places)}/{len(words)}, error (cm) {errors}", flush=True)
    print(f"all placed at {placed_all}/{args.seeds} seeds; {wrong} objects named wrong (>3 cm); worst right {worst:.2f} cm")


if __name__ == "__main__":
    main()
