"""Record the FindImposter shape exemplars, and score the FindImposter cue readers.

``calibrate`` renders the cue frame (the reset frame: the cue phase lasts at least one step) of ``--episodes``
episodes per shape task at development seeds ``--seed`` + i (6000 by default: neither MIKASA's evaluation seeds
4242424242 + i nor the 5000 + i the figures are quoted at), finds each object in view as the reader does
(``objects_in_view``), names it by the segmentation camera (ground truth, calibration only; an object whose pixels
merge with another's is skipped) and writes each object's place, crop and shape (``ShapeExemplars``) to
``sb3_memret/tasks/mikasa/assets/imposter_exemplars/<env id>.npz``.

``evaluate`` reads the cue frame of ``--episodes`` episodes per task at seeds ``--seed`` + i through the task's
own reader (``FindImposterTask.read_cue``) and scores it against the segmentation camera: frames read exactly
(the set of N - 1 shown), frames read as no set (objects merged or one out of sight), frames read wrong; and per
word, the share of the objects shown that the reader named right (``assign_shown``).

``calibrate-remember`` does the same for RememberShape's and RememberShapeAndColor's camera expert from each
episode's choice frame (the first with two or more of the task's objects in view, zero actions), its objects found
and cut apart as that expert's reader finds them (``objects_in_view`` with the task's count), each named by the
object that owns at least ``OWNED`` of its pixels, into ``sb3_memret/tasks/mikasa/assets/remember_exemplars/``: the
choice lays out objects where FindImposter's cue does not, and neighbours that touch there are seen cut apart.

    .venv/bin/python scripts/calibrate_imposter.py calibrate [--episodes 200] [--seed 6000]
    .venv/bin/python scripts/calibrate_imposter.py calibrate-remember [--episodes 200] [--seed 6000]
    .venv/bin/python scripts/calibrate_imposter.py evaluate [--episodes 60] [--seed 5000] [--tasks ...]
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

SHAPE_TASKS = ("FindImposterShape3-VLA-v0", "FindImposterShape5-VLA-v0", "FindImposterShape9-VLA-v0",
               "FindImposterShapeAndColor3x2-VLA-v0", "FindImposterShapeAndColor3x3-VLA-v0",
               "FindImposterShapeAndColor5x3-VLA-v0")
ALL_TASKS = ("FindImposterColor3-VLA-v0", "FindImposterColor5-VLA-v0", "FindImposterColor9-VLA-v0") + SHAPE_TASKS
REMEMBER_TASKS = ("RememberShape3-VLA-v0", "RememberShape5-VLA-v0", "RememberShape9-VLA-v0",
                  "RememberShapeAndColor3x2-VLA-v0", "RememberShapeAndColor3x3-VLA-v0",
                  "RememberShapeAndColor5x3-VLA-v0")
OWNED = 0.8  # a cut object is named by the object owning this share of its pixels (else skipped)
CHOICE_WITHIN = 40  # control steps: the choice shows by then at every seed (the cue and delay take 5-10)


def cue_frames(task, seeds, choice: bool = False):
    """(rgb, object index per pixel (-1: none)) of each seed's reset frame, from the raw env with segmentation; with
    ``choice``, of its first frame (zero actions) that shows two or more of the task's objects instead."""
    import gymnasium as gym

    from sb3_memret.common.rendering import use_cpu_renderer

    use_cpu_renderer()
    import mikasa_robo_suite.vla.memory_envs  # noqa: F401

    env = gym.make(task.name, num_envs=1, obs_mode="rgb+segmentation", control_mode="pd_ee_delta_pose",
                   render_backend="cpu", sim_backend="cpu", reward_mode="normalized_dense", robot_uids="panda")
    base = env.unwrapped
    actors = base.cubes if hasattr(base, "cubes") else base.shape_actors
    ids = {int(actors[k]._objs[0].per_scene_id): k for k in actors}
    try:
        for seed in seeds:
            obs, _ = env.reset(seed=int(seed))
            for _ in range(CHOICE_WITHIN if choice else 1):
                camera = obs["sensor_data"]["base_camera"]
                seg = camera["segmentation"][0, ..., 0].numpy()
                owner = np.full(seg.shape, -1)
                for scene_id, k in ids.items():
                    owner[seg == scene_id] = k
                if not choice or len(set(np.unique(owner).tolist()) - {-1}) >= 2:
                    yield camera["rgb"][0].numpy(), owner
                    break
                obs, *_ = env.step(np.zeros(env.action_space.shape))
            else:
                raise RuntimeError(f"{task.name} seed {seed}: no frame within {CHOICE_WITHIN} steps showed the choice")
    finally:
        env.close()


def owner_of(blob: np.ndarray, owner: np.ndarray, share: float = 1.0) -> int | None:
    """The object owning at least ``share`` of a blob's pixels (by default all: None when they belong to several,
    merged, or none)."""
    owners, counts = np.unique(owner[blob], return_counts=True)
    best = int(np.argmax(np.where(owners >= 0, counts, -1)))
    return int(owners[best]) if owners[best] >= 0 and counts[best] >= share * blob.sum() else None


def record_exemplars(env_id: str, frames, cut, name_of, path) -> None:
    """Write ``env_id``'s shape exemplars to ``path``: each object ``cut(rgb)`` finds in the (rgb, owner) ``frames``
    that ``name_of(blob, owner)`` names a shape (None: skipped), its place and crop as the readers see them."""
    from sb3_memret.tasks.mikasa.find_imposter.perception import ShapeExemplars, object_crop

    centres, crops, shapes = [], [], []
    for rgb, owner in frames:
        for seen in cut(rgb):
            shape = name_of(seen.mask, owner)
            if shape is not None:
                centre, crop = object_crop(rgb, seen.mask)
                centres.append(centre)
                crops.append(crop)
                shapes.append(shape)
    ShapeExemplars(np.array(centres, dtype=np.float32), np.array(crops, dtype=np.float32), np.array(shapes)).save(path)
    print(f"{env_id}: {dict(Counter(shapes))} -> {path}", flush=True)


def calibrate(episodes: int, seed: int) -> None:
    from sb3_memret.tasks import make_task
    from sb3_memret.tasks.mikasa.find_imposter.perception import EXEMPLARS_DIR, objects_in_view

    EXEMPLARS_DIR.mkdir(parents=True, exist_ok=True)
    for env_id in SHAPE_TASKS:
        task = make_task(env_id)

        def name_of(blob, owner, task=task):
            k = owner_of(blob, owner)
            return None if k is None else task.candidate(task.words[k])[1]

        record_exemplars(env_id, cue_frames(task, range(seed, seed + episodes)), lambda rgb: objects_in_view(rgb, 3),
                         name_of, EXEMPLARS_DIR / f"{env_id}.npz")


def calibrate_remember(episodes: int, seed: int) -> None:
    from sb3_memret.tasks import make_task
    from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES
    from sb3_memret.tasks.mikasa.find_imposter.perception import objects_in_view
    from sb3_memret.tasks.mikasa.remember.shape_camera_expert import REMEMBER_EXEMPLARS_DIR, candidates

    REMEMBER_EXEMPLARS_DIR.mkdir(parents=True, exist_ok=True)
    for env_id in REMEMBER_TASKS:
        task = make_task(env_id)
        words = list(task.words)
        named = candidates(env_id, words)
        n_colours = 1 + max(COLOUR_NAMES.index(colour or "blue") for colour, _ in named)

        def name_of(blob, owner, named=named):
            k = owner_of(blob, owner, OWNED)
            return None if k is None else named[k][1]

        record_exemplars(env_id, cue_frames(task, range(seed, seed + episodes), choice=True),
                         lambda rgb, n=n_colours, m=len(words): objects_in_view(rgb, n, m), name_of,
                         REMEMBER_EXEMPLARS_DIR / f"{env_id}.npz")


def evaluate(tasks: list[str], episodes: int, seed: int) -> None:
    from sb3_memret.tasks import make_task
    from sb3_memret.tasks.mikasa.find_imposter.perception import assign_shown, task_exemplars

    for env_id in tasks:
        task = make_task(env_id)
        exemplars = task_exemplars(env_id) if task.reads_shapes else None
        frames, named, right = Counter(), Counter(), Counter()
        for rgb, owner in cue_frames(task, range(seed, seed + episodes)):
            truth = tuple(task.words[k] for k in sorted(set(np.unique(owner).tolist()) - {-1}))
            read = task.read_cue(rgb)
            frames["exact" if read == truth else "no set" if read is None else "wrong"] += 1
            for word in truth:
                named[word] += 1
            assigned = assign_shown(rgb, [task.candidate(w) for w in task.words], task.n_words - 1, exemplars)
            for seen, j in assigned or ():
                k = owner_of(seen.mask, owner)
                right[task.words[j]] += k is not None and task.words[k] == task.words[j]
        per_word = ", ".join(f"{w} {right[w]}/{named[w]}" for w in task.words)
        print(f"{env_id}: cue frames read exactly {frames['exact']}/{episodes}, as no set {frames['no set']}, "
              f"wrong {frames['wrong']}; objects named right per word (of those shown): {per_word}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=("calibrate", "calibrate-remember", "evaluate"))
    parser.add_argument("--episodes", type=int, default=None, help="default: 200 to calibrate, 60 to evaluate")
    parser.add_argument("--seed", type=int, default=None,
                        help="first seed: default 6000 to calibrate, 5000 to evaluate")
    parser.add_argument("--tasks", nargs="+", default=list(ALL_TASKS))
    args = parser.parse_args()
    if args.command == "calibrate":
        calibrate(args.episodes or 200, 6000 if args.seed is None else args.seed)
    elif args.command == "calibrate-remember":
        calibrate_remember(args.episodes or 200, 6000 if args.seed is None else args.seed)
    else:
        evaluate(args.tasks, args.episodes or 60, 5000 if args.seed is None else args.seed)


if __name__ == "__main__":
    main()
