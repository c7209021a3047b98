"""How far off are a camera controller's perception estimates? Per perceived entry, on demonstration frames.

Runs a trained camera-reading learned controller's perception head on the validation episodes its finetune held
out (the split rebuilt from ``--seed`` and ``--validation-fraction``, finetune's defaults) of the datasets it was
trained on (``--split training``: on its training episodes instead, to tell overfitting from what the cameras cannot
tell; ``--split all``: on every episode, for datasets no controller compared saw), and prints, per task, the
normalised MSE over the task's own entries and the median xy error of its objects in sight; then, per perceived
entry, the normalised MSE and the median absolute error in the state's units; for entries named ``<object>_x`` /
``_y`` with a ``<object>_visible`` flag (MIKASA's cubes), also the median xy error over the frames where the object is
in sight. For a policy with a pointer (``finetune --pointer``), also the object each of its training prompts points
at, and how sharply: a pointer that learned nothing spreads its weight.

    python scripts/perception_error.py sb3_memret/controllers/checkpoints/RememberColor9-VLA-v0-camera \\
        runs/stage1-RememberColor9-VLA-v0/demos --task RememberColor9-VLA-v0

A multi-task controller reads its datasets as ``finetune --tasks`` does (each DATASET's task, in order); given some
of its tasks only, the entries of the others are left out. A controller on MIKASA's harness proprioception gets it
derived from the datasets' hand pose and fingers, as its finetune did.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import torch

from sb3_memret.controllers.harness_proprio import reads_harness_proprio
from sb3_memret.controllers.learned import LearnedPolicy
from sb3_memret.controllers.learned.configuration import perceived_objects
from sb3_memret.controllers.learned.modeling import pointer_ambiguity
from sb3_memret.controllers.learned.processing import LearnedPolicyProcessor, PromptTokenizer, state_columns
from sb3_memret.stage1.datasets import load_demonstrations, load_task_demonstrations, validation_episodes
from sb3_memret.stage1.finetune import FinetuneSettings, camera_inputs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--task", default="drawer")
    parser.add_argument("--tasks", default=None, help="each DATASET's task, a comma list in their order")
    parser.add_argument("--split", choices=["validation", "training", "all"], default="validation",
                        help="the finetune's held-out episodes, its training ones, or every episode (datasets it "
                             "never saw, to compare controllers trained on different data)")
    parser.add_argument("--seed", type=int, default=FinetuneSettings.seed, help="the finetune's --seed")
    parser.add_argument("--validation-fraction", type=float, default=FinetuneSettings.validation_fraction)
    parser.add_argument("--frames", type=int, default=1500, help="validation frames drawn at most")
    args = parser.parse_args()

    policy = LearnedPolicy.from_pretrained(args.checkpoint)
    names = policy.config.perceived_names
    if not names:
        raise SystemExit(f"{args.checkpoint} estimates nothing: its config has no perceived_names")
    if args.tasks is None:
        demos, tasks = load_demonstrations(args.datasets, args.task), None
    else:
        task_names = args.tasks.split(",")
        if len(task_names) != len(args.datasets):
            raise SystemExit(f"{len(task_names)} tasks for {len(args.datasets)} datasets: name each DATASET's task")
        by_task: dict[str, list[str]] = {}
        for task_name, root in zip(task_names, args.datasets):
            by_task.setdefault(task_name, []).append(root)
        demos, tasks = load_task_demonstrations(by_task)
    missing = [name for name in names if name not in demos.state_names]
    if missing and tasks is None:
        raise SystemExit(f"the dataset's state has no entries {missing}: record it for task {policy.config.task!r}")
    if missing:  # some of a multi-task controller's tasks: the others' entries are unknown in every frame
        demos = replace(demos, state_names=demos.state_names + tuple(missing),
                        states=np.pad(demos.states, ((0, 0), (0, len(missing)))),
                        known=np.pad(demos.known, ((0, 0), (0, len(missing)))))
    if reads_harness_proprio(policy.config.state_names):  # derived from the hand pose and fingers, as finetune does
        demos = demos.with_harness_proprio()
    rng = np.random.default_rng(args.seed)
    is_val = np.isin(demos.episodes, validation_episodes(demos.episodes, args.validation_fraction, rng))
    held = np.flatnonzero({"validation": is_val, "training": ~is_val, "all": np.ones_like(is_val)}[args.split])
    if not len(held):
        raise SystemExit(f"no {args.split} episodes (--validation-fraction {args.validation_fraction})")
    idx = np.sort(np.random.default_rng(0).choice(held, size=min(args.frames, len(held)), replace=False))
    tokenizer = PromptTokenizer()
    processor = LearnedPolicyProcessor(policy.config, tokenizer=tokenizer)  # the inputs as training and acting build them
    features = camera_inputs(policy, processor, {k: v.take(idx) for k, v in demos.images.items()},
                             policy.config.image_features, cache=False)
    cameras = [processor.camera(f) if policy.trunk is None else f.float() for f in features]
    with torch.no_grad():  # heads conditioned on the prompt (image_film) read each frame's own prompt
        prompts = policy.encode_prompts(*tokenizer(demos.tasks))[torch.from_numpy(demos.task_ids[idx])]
    columns = state_columns(demos.state_names, names, "the datasets' state")
    states = processor.state(demos.states[idx], processor.state_columns(demos.state_names, "the datasets' state"))
    estimates = policy.estimate_perceived(cameras, prompts, states)
    labels = torch.from_numpy(demos.states[idx][:, columns])
    error = estimates - labels
    normalised_error = error / policy.perceived_std
    known = (torch.ones_like(labels, dtype=torch.bool) if demos.known is None else
             torch.from_numpy(demos.known[idx][:, columns]))
    where = "every episode of the datasets" if args.split == "all" else f"the finetune's {args.split} episodes"
    print(f"{len(idx)} of the {len(held)} frames of {where}")
    objects = [n.removesuffix("_visible") for n in names if n.endswith("_visible")]
    located = [o for o in objects if f"{o}_x" in names and f"{o}_y" in names and known[:, names.index(f"{o}_x")].any()]

    def xy_errors(rows: torch.Tensor) -> torch.Tensor:
        """The xy errors (m) of every located object in sight in the ``rows`` frames whose task has it."""
        errors = []
        for obj in located:
            seen = rows & (labels[:, names.index(f"{obj}_visible")] > 0.5) & known[:, names.index(f"{obj}_x")]
            errors.append(error[seen][:, [names.index(f"{obj}_x"), names.index(f"{obj}_y")]].norm(dim=1))
        return torch.cat(errors) if errors else torch.zeros(0)

    if tasks is not None:
        print("\n| task | frames | normalised MSE over its own entries | median xy error of objects in sight (m) |"
              "\n|---|---|---|---|")
        # a frame's task: the one its dataset was named with (tasks sharing a layout, as FindImposter and Remember
        # do, are told apart by their datasets, not their entries); datasets are read task by task
        frame_task = np.repeat([i for i, roots in enumerate(by_task.values()) for _ in roots], demos.spans)[idx]
        for i, task in enumerate(tasks):
            rows = torch.from_numpy(frame_task == i)
            mask = known[rows]
            value = float(((normalised_error[rows] ** 2) * mask).sum() / mask.sum().clamp_min(1))
            xy = xy_errors(rows)
            print(f"| {task.name} | {int(rows.sum())} | {value:.3f} | "
                  f"{f'{float(xy.median()):.4f}' if len(xy) else '-'} |")
        print()
    print("| entry | normalised MSE | median abs error |\n|---|---|---|")
    for i, name in enumerate(names):  # over the frames whose task has the entry
        rows = known[:, i]
        if not rows.any():
            continue
        print(f"| {name} | {float((normalised_error[rows, i] ** 2).mean()):.3f} | "
              f"{float(error[rows, i].abs().median()):.4f} |")
    if located:
        print("\n| object | frames in sight | median xy error |\n|---|---|---|")
    for obj in located:
        seen = labels[:, names.index(f"{obj}_visible")] > 0.5
        xy = error[seen][:, [names.index(f"{obj}_x"), names.index(f"{obj}_y")]].norm(dim=1)
        print(f"| {obj} | {int(seen.sum())} | {float(xy.median()) if len(xy) else float('nan'):.4f} |")

    if policy.pointer is not None:
        prompts = list(policy.config.training_prompts)
        with torch.no_grad():
            weights = policy.pointer.weights(policy.encode_prompts(*tokenizer(prompts)))
        pointed = perceived_objects(names)[0]
        print("\n| training prompt | object pointed at | weight |\n|---|---|---|")
        for prompt, row in zip(prompts, weights):
            print(f"| {prompt} | {pointed[int(row.argmax())]} | {float(row.max()):.2f} |")
        print(f"\npointer ambiguity {float(pointer_ambiguity(weights)):.3f} (0: each prompt points at an object of its "
              f"own; {np.log(len(pointed)):.2f}: none tells)")


if __name__ == "__main__":
    main()
