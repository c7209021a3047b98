"""Memory tasks behind one interface (``Task``), and the registry that ``--task`` names them by.

Built in: ``drawer`` (DrawerCubeTakeOut-v1, the seed's task) and MIKASA-Robo-VLA's memory tasks: those of its
short split, the cue family's -Long variants and the colour-cue tasks (Bunch-, Seq-, ChainOfColors 3/5/7 and their
-Long) (``RememberColor3-VLA-v0``, ``FindImposterShape9-VLA-v0``, ``ChainOfColors7-Long-VLA-v0``, ...
``task_names()`` lists them; the ``mikasa-robo-suite`` package, installed by ``make install``). A task of your
own is one module: subclass ``Task`` and ``register_task("name", MyTask)``, or name it ``package.module:Class``; see
the docs' "Writing your own task". Task modules import only when a task is made, so listing names is cheap.
"""

from __future__ import annotations

import importlib
from typing import Any, Callable, Mapping

from sb3_memret.tasks.base import EnvFrame, Episode, Predicates, Task, Writer

DEFAULT_TASK = "drawer"
_FACTORIES: dict[str, Callable[[], Task]] = {}
# why a registered task cannot run here (e.g. a missing asset), or None when it can: checked whenever it is named
_UNAVAILABLE: dict[str, Callable[[], str | None]] = {}


def register_task(name: str, factory: Callable[[], Task], unavailable: Callable[[], str | None] | None = None) -> None:
    """Make ``name`` a task ``--task`` and ``make_task`` accept; ``factory()`` builds it. ``unavailable()``, if
    given, says why it cannot run here (a missing asset: what and how to get it), or None when it can."""
    if not name or not isinstance(name, str):
        raise ValueError(f"a task name must be a non-empty string, got {name!r}")
    if name in _FACTORIES:
        raise ValueError(f"task {name!r} is already registered")
    _FACTORIES[name] = factory
    if unavailable is not None:
        _UNAVAILABLE[name] = unavailable


def task_names() -> list[str]:
    """Every registered task name."""
    return list(_FACTORIES)


def make_task(task: str | Task) -> Task:
    """The task ``task`` names (or ``task`` itself): a registered name, or ``package.module:Class`` (a
    task class of your own, imported; no registration needed). Else a ValueError listing the names."""
    if isinstance(task, Task):
        return task
    if isinstance(task, str) and ":" in task:
        return _import_task(task)
    return _FACTORIES[check_task_name(task)]()


def _import_task(spec: str) -> Task:
    """The task ``package.module:Class`` names: ``Class`` must be a ``Task`` subclass built with no arguments."""
    module_name, _, attr = spec.partition(":")
    expected = "package.module:Class naming a sb3_memret.tasks.Task subclass whose __init__ needs no arguments"
    try:
        factory = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as err:
        raise ValueError(f"task {spec!r}: cannot import {attr!r} from module {module_name!r} ({err}); expected "
                         f"{expected}, its module importable (its folder on PYTHONPATH)") from None
    if not (isinstance(factory, type) and issubclass(factory, Task)):
        kind = "a class" if isinstance(factory, type) else f"a {type(factory).__name__}"
        raise ValueError(f"task {spec!r}: {module_name}.{attr} is {kind}, not a Task subclass; expected {expected}")
    try:
        return factory()
    except TypeError as err:  # abstract methods left, or arguments without defaults
        raise ValueError(f"task {spec!r}: {attr}() fails ({err}); expected {expected}") from None


def check_task_name(name: str) -> str:
    """``name`` if it is a registered task that can run here or a ``module:Class`` that imports; else a one-line
    ValueError that says why it cannot run or lists the names."""
    if name in _FACTORIES:
        reason = _UNAVAILABLE[name]() if name in _UNAVAILABLE else None
        if reason is not None:
            raise ValueError(f"task {name!r} is not available: {reason}")
        return name
    if ":" in str(name):
        _import_task(name)
        return name
    raise ValueError(f"unknown task {name!r}; expected one of {task_names()}")


def task_in(env_kwargs: Mapping[str, Any]) -> str | Task:
    """The one task a run's ``env_kwargs`` name: their ``task``, else the default task (a run saved before its
    settings named a task played the drawer); a learner across tasks names its ``tasks`` instead."""
    return env_kwargs.get("task", DEFAULT_TASK)


def _lazy(module: str, attr: str, *args: str) -> Callable[[], Task]:
    """A factory that imports ``module`` only when the task is made."""
    return lambda: getattr(importlib.import_module(module), attr)(*args)


register_task(DEFAULT_TASK, _lazy("sb3_memret.tasks.drawer", "DrawerTask"))
for _env_id in ("RememberColor3-VLA-v0", "RememberColor5-VLA-v0", "RememberColor9-VLA-v0"):
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.remember.color", "RememberColorTask", _env_id))
register_task("RememberShape3-VLA-v0",
              _lazy("sb3_memret.tasks.mikasa.remember.shape", "RememberShapeTask", "RememberShape3-VLA-v0"))
for _family in ("BunchOfColors", "SeqOfColors", "ChainOfColors"):  # 3, 5, 7 colours; 400 steps and -Long
    for _size in ("3", "5", "7"):
        for _env_id in (f"{_family}{_size}-VLA-v0", f"{_family}{_size}-Long-VLA-v0"):
            register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.seq_of_colors.task", "SeqOfColorsTask", _env_id))
register_task("TakeItBack-VLA-v0", _lazy("sb3_memret.tasks.mikasa.take_it_back.task", "TakeItBackTask", "TakeItBack-VLA-v0"))
for _env_id in ("RememberShape5-VLA-v0", "RememberShape9-VLA-v0"):
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.remember.shape", "RememberShapeTask", _env_id))
for _env_id in ("RememberShapeAndColor3x2-VLA-v0", "RememberShapeAndColor3x3-VLA-v0", "RememberShapeAndColor5x3-VLA-v0"):
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.remember.shape_and_color", "RememberShapeAndColorTask",
                                 _env_id))
for _class, _sizes in (("FindImposterColorTask", ("3", "5", "9")), ("FindImposterShapeTask", ("3", "5", "9")),
                       ("FindImposterShapeAndColorTask", ("3x2", "3x3", "5x3"))):
    for _size in _sizes:
        _env_id = f"{_class.removesuffix('Task')}{_size}-VLA-v0"
        register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.find_imposter.task", _class, _env_id))
for _module, _class, _sizes in (("color", "RememberColorTask", ("3", "5", "9")),
                                ("shape", "RememberShapeTask", ("3", "5", "9")),
                                ("shape_and_color", "RememberShapeAndColorTask", ("3x2", "3x3", "5x3"))):
    for _size in _sizes:  # MIKASA's 600-step variants of the cue tasks
        _env_id = f"{_class.removesuffix('Task')}{_size}-Long-VLA-v0"
        register_task(_env_id, _lazy(f"sb3_memret.tasks.mikasa.remember.{_module}", _class, _env_id))

for _env_id in ("ShellGameTouch-VLA-v0", "ShellGamePush-VLA-v0", "ShellGameColorLampTouch-VLA-v0",
                "ShellGameShuffleTouch-VLA-v0", "ShellGameShuffleColorLampTouch-VLA-v0",  # they need the YCB mug
                "ShellGameShuffleTouch-Long-VLA-v0", "ShellGameShuffleColorLampTouch-Long-VLA-v0"):
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.shell_game.task", "shell_game_task", _env_id),
                  lambda: importlib.import_module("sb3_memret.tasks.mikasa.shell_game.assets").ycb_mug_missing())
for _env_id in ("InterceptSlow-VLA-v0", "InterceptMedium-VLA-v0", "InterceptFast-VLA-v0", "InterceptGrabSlow-VLA-v0",
                "InterceptGrabMedium-VLA-v0", "InterceptGrabFast-VLA-v0"):
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.intercept.task", "InterceptTask", _env_id))
for _env_id in ("RotateLenientPos-VLA-v0", "RotateLenientPosNeg-VLA-v0", "RotateStrictPos-VLA-v0",
                "RotateStrictPosNeg-VLA-v0"):
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.rotate.task", "RotateTask", _env_id))
for _env_id in ("BlinkCountButtonPressEasy-VLA-v0", "BlinkCountButtonPressMedium-VLA-v0",  # they build MIKASA's lamp
                "BlinkCountButtonPressHard-VLA-v0", "BlinkCountButtonPressEasy-Long-VLA-v0",
                "BlinkCountButtonPressMedium-Long-VLA-v0", "BlinkCountButtonPressHard-Long-VLA-v0"):
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.blink_count.task", "BlinkCountTask", _env_id),
                  lambda: importlib.import_module("sb3_memret.tasks.mikasa.core.lamp_asset").ensure_lamp_asset())
for _env_id in ("GatherAndRecall1-VLA-v0", "GatherAndRecall3-VLA-v0", "GatherAndRecall5-VLA-v0",  # the lamp's bulb
                "GatherAndRecall7-VLA-v0", "GatherAndRecall9-VLA-v0"):
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.gather_and_recall.task", "GatherAndRecallTask", _env_id),
                  lambda: importlib.import_module("sb3_memret.tasks.mikasa.core.lamp_asset").ensure_lamp_asset())
for _env_id in ("TimedTransferEasy-VLA-v0", "TimedTransferMedium-VLA-v0", "TimedTransferHard-VLA-v0",  # the lamp's bulb
                "TimedTransferEasy-Long-VLA-v0", "TimedTransferMedium-Long-VLA-v0", "TimedTransferHard-Long-VLA-v0"):
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.timed_transfer.task", "TimedTransferTask", _env_id),
                  lambda: importlib.import_module("sb3_memret.tasks.mikasa.core.lamp_asset").ensure_lamp_asset())
for _env_id in ("TraceShapeEasy-VLA-v0", "TraceShapeMedium-VLA-v0", "TraceShapeHard-VLA-v0"):  # the lamp's bulb
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.trace_shape.task", "TraceShapeTask", _env_id),
                  lambda: importlib.import_module("sb3_memret.tasks.mikasa.core.lamp_asset").ensure_lamp_asset())
for _env_id in ("TraceShapeSeqEasy-VLA-v0", "TraceShapeSeqMedium-VLA-v0", "TraceShapeSeqHard-VLA-v0"):  # the lamp's bulb
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.trace_shape.sequence", "TraceShapeSeqTask", _env_id),
                  lambda: importlib.import_module("sb3_memret.tasks.mikasa.core.lamp_asset").ensure_lamp_asset())

__all__ = ["DEFAULT_TASK", "EnvFrame", "Episode", "Predicates", "Task", "Writer", "check_task_name",
           "make_task", "register_task", "task_in", "task_names"]
for _env_id in ("BatteriesCheckerEasy-3-VLA-v0", "BatteriesCheckerEasy-6-VLA-v0",  # the lamp's bulb
                "BatteriesCheckerHard-3-VLA-v0", "BatteriesCheckerHard-6-VLA-v0"):
    register_task(_env_id, _lazy("sb3_memret.tasks.mikasa.batteries_checker.task", "BatteriesCheckerTask", _env_id),
                  lambda: importlib.import_module("sb3_memret.tasks.mikasa.core.lamp_asset").ensure_lamp_asset())
