"""The learned controllers shipped in the package, by task and ``--controller`` name: where each checkpoint lies
and the make command that rebuilds it. Paths only (no torch, no tasks), so a task can ask what ships for it."""

from __future__ import annotations

from pathlib import Path

CHECKPOINTS = Path(__file__).resolve().parent / "checkpoints"
# the 33 short-split tasks the scripted experts run (the nineteen won by touching the object a fact names, then
# intercept, rotate, count and press, gather, act on time) and SeqOfColors3, whose prompt also says which cubes were
# touched (progress as memory): one camera controller on the harness's inputs alone (`make controller-multitask`)
MULTITASK_TASKS = ("RememberColor3-VLA-v0", "RememberShape3-VLA-v0", "RememberColor5-VLA-v0", "TakeItBack-VLA-v0",
                   "RememberShape5-VLA-v0", "FindImposterColor3-VLA-v0", "RememberShapeAndColor3x2-VLA-v0",
                   "RememberColor9-VLA-v0", "FindImposterShape3-VLA-v0", "RememberShapeAndColor3x3-VLA-v0",
                   "FindImposterColor5-VLA-v0", "RememberShape9-VLA-v0", "FindImposterShapeAndColor3x2-VLA-v0",
                   "RememberShapeAndColor5x3-VLA-v0", "FindImposterColor9-VLA-v0", "FindImposterShape5-VLA-v0",
                   "FindImposterShapeAndColor3x3-VLA-v0", "FindImposterShape9-VLA-v0",
                   "FindImposterShapeAndColor5x3-VLA-v0", "InterceptSlow-VLA-v0", "InterceptMedium-VLA-v0",
                   "InterceptFast-VLA-v0", "InterceptGrabSlow-VLA-v0", "InterceptGrabMedium-VLA-v0",
                   "InterceptGrabFast-VLA-v0", "RotateLenientPos-VLA-v0", "RotateLenientPosNeg-VLA-v0",
                   "RotateStrictPos-VLA-v0", "RotateStrictPosNeg-VLA-v0", "BlinkCountButtonPressEasy-VLA-v0",
                   "BlinkCountButtonPressMedium-VLA-v0", "GatherAndRecall1-VLA-v0", "TimedTransferEasy-VLA-v0",
                   "SeqOfColors3-VLA-v0")
# tasks whose shipped ``learned`` controller reads their prompts but does not yet do the task, told the true fact at
# development seeds 5000-5019 (their experts win nearly every episode): SeqOfColors3 0 of 6 (it does not finish the
# sequence; seeds 5000-5005), RotateLenientPos 5, RotateLenientPosNeg 3 and RotateStrictPos 9 of 20 (the push that
# turns the peg is half learned); a command runs their expert unless ``--controller learned`` asks
LEARNED_NOT_DEFAULT = frozenset({"SeqOfColors3-VLA-v0", "RotateLenientPos-VLA-v0", "RotateLenientPosNeg-VLA-v0",
                                 "RotateStrictPos-VLA-v0"})
# shipped checkpoints by (task, controller name): the folder (its recipe.yml: the finetune's recipe), and the make
# command that rebuilds it from nothing (demonstrations, then the recipe's finetune). ``learned`` is
# the camera-reading controller (cameras and what the robot reads of itself): on MULTITASK_TASKS one network across
# all of them, the prompt telling them apart. ``learned-task`` is a MIKASA task's own camera controller, trained on
# that task alone. ``learned-state`` is the drawer's policy on the simulator's state, whose cube detection is perfect
# perception.
SHIPPED: dict[tuple[str, str], tuple[Path, str]] = {
    ("drawer", "learned"): (CHECKPOINTS / "drawer-camera", "make controller-camera"),
    ("drawer", "learned-state"): (CHECKPOINTS / "drawer-learned", "make controller"),
    ("drawer", "learned-objects"): (CHECKPOINTS / "drawer-objects-learned", "make controller-objects"),  # state
    **{(task, "learned"): (CHECKPOINTS / "mikasa-multitask-camera", "make controller-multitask")
       for task in MULTITASK_TASKS},
    ("RememberColor3-VLA-v0", "learned-task"): (CHECKPOINTS / "RememberColor3-VLA-v0-camera",
                                                "make controller-mikasa MIKASA_TASK=RememberColor3-VLA-v0"),
    ("RememberColor5-VLA-v0", "learned-task"): (CHECKPOINTS / "RememberColor5-VLA-v0-camera",
                                                "make controller-mikasa MIKASA_TASK=RememberColor5-VLA-v0 "
                                                "MIKASA_STEPS=2000 MIKASA_DAGGER=150"),
    ("RememberColor9-VLA-v0", "learned-task"): (CHECKPOINTS / "RememberColor9-VLA-v0-camera",
                                                "make controller-mikasa MIKASA_TASK=RememberColor9-VLA-v0 "
                                                "MIKASA_EPISODES=800 MIKASA_STEPS=3000 MIKASA_DAGGER=200"),
    ("RememberShape3-VLA-v0", "learned-task"): (CHECKPOINTS / "RememberShape3-VLA-v0-camera",
                                                "make controller-mikasa MIKASA_TASK=RememberShape3-VLA-v0 "
                                                "MIKASA_STEPS=2000 MIKASA_DAGGER=150"),
    ("TakeItBack-VLA-v0", "learned-task"): (CHECKPOINTS / "TakeItBack-VLA-v0-camera",
                                            "make controller-mikasa MIKASA_TASK=TakeItBack-VLA-v0 MIKASA_EPISODES=300 "
                                            "MIKASA_STEPS=2500 MIKASA_DAGGER=116"),
}


def shipped_names(task: str = "drawer") -> list[str]:
    """The shipped learned controllers of ``task``, by ``--controller`` name."""
    return sorted(name for t, name in SHIPPED if t == task)


def default_checkpoint(name: str = "learned", task: str = "drawer") -> Path:
    """The checkpoint ``--controller NAME`` names on ``task``: trained by its make target and shipped in the
    package."""
    if (task, name) not in SHIPPED:
        raise ValueError(f"no shipped learned controller {name!r} for task {task!r}; shipped are "
                         f"{shipped_names(task) or 'none'} (or train one: sb3-memret demos, then finetune)")
    folder, command = SHIPPED[task, name]
    if not (folder / "model.safetensors").is_file():
        raise FileNotFoundError(f"the shipped learned controller {name!r} of task {task!r} is missing from {folder}; "
                                f"rebuild it with `{command}` (demos, then finetune)")
    return folder


__all__ = ["CHECKPOINTS", "LEARNED_NOT_DEFAULT", "MULTITASK_TASKS", "SHIPPED", "default_checkpoint", "shipped_names"]
