"""The CLI's ``--controller`` values: parsing them, and building the controller each names for a task.

Accepted values (``CONTROLLER_SPECS``):

- ``learned``: the task's shipped camera-reading learned controller (both cameras and what the robot
  reads of itself; the drawer's: ``make controller-camera``; on seven MIKASA tasks one controller across them:
  ``make controller-multitask``).
- ``learned-task``: a MIKASA task's own camera controller, trained on that task alone (``make controller-mikasa``).
- ``learned-state``: the drawer's learned controller on the simulator's state (its cube detection is
  perfect perception; ``make controller`` rebuilds it): the drawer's default (``Task.default_controller``).
- ``learned-objects``: the state policy trained with several objects in the drawers, the instruction
  naming the target (``make controller-objects``).
- ``learned:/PATH/TO/CHECKPOINT[?device=DEV]``: a checkpoint ``sb3-memret finetune`` wrote.
- ``scripted``: the scripted expert (CPU); it obeys its prompt by construction.
- ``scripted-camera``: the scripted expert on what MIKASA's harness gives a policy alone (the objects read from the
  base camera with its shipped calibration, the hand's motion from its pose): a protocol entry, where ``scripted``
  (a simulated object detector) is a privileged upper bound; the tasks whose family has one
  (``sb3_memret.tasks.mikasa.camera_experts``).
- ``openpi://HOST:PORT[?timeout=S&attempts=N&chunk_len=H]``: π0.5 served by openpi
  (needs the ``openpi`` extra); ``timeout`` bounds each inference in seconds.
- ``lerobot:/PATH/TO/CHECKPOINT[?adapter=PATH&tokenizer=PATH&device=DEV]``: lerobot's PI05Policy
  in-process, with an optional peft LoRA adapter folder and a local
  PaliGemma tokenizer folder.

The π0.5 controllers are imported only when named: their dependencies are slow to import.
"""

from __future__ import annotations

from typing import Any, Callable
from urllib.parse import parse_qsl, urlsplit

from sb3_memret.controllers.base import FrozenController
from sb3_memret.tasks import Task, make_task

SHIPPED_NAMES = ("learned", "learned-task", "learned-state", "learned-objects")
CONTROLLER_SPECS = (
    "learned",
    "learned-task",
    "learned-state",
    "learned-objects",
    "learned:/PATH/TO/CHECKPOINT[?device=DEV]",
    "scripted",
    "scripted-camera",
    "openpi://HOST:PORT[?timeout=S&attempts=N&chunk_len=H]",
    "lerobot:/PATH/TO/CHECKPOINT[?adapter=PATH&tokenizer=PATH&device=DEV]",
)
OPENPI_OPTIONS: dict[str, Callable[[str], Any]] = {"timeout": float, "attempts": int, "chunk_len": int}
LEARNED_OPTIONS: dict[str, Callable[[str], Any]] = {"device": str}
LEROBOT_OPTIONS: dict[str, Callable[[str], Any]] = {"adapter": str, "tokenizer": str, "device": str}


def make_controller(spec: str, task: str | Task) -> FrozenController:
    """Build the controller a CLI ``--controller`` value names for ``task`` (a name or a ``Task``), or raise
    a ValueError listing the forms. ``scripted`` is the task's expert, the ``SHIPPED_NAMES`` its shipped learned
    controllers."""
    if spec == "scripted":
        return make_task(task).expert()
    if spec == "scripted-camera":
        from sb3_memret.tasks.mikasa.camera_experts import camera_expert

        return camera_expert(make_task(task))
    if spec in SHIPPED_NAMES:
        from sb3_memret.controllers.learned import LearnedController
        from sb3_memret.controllers.shipped import default_checkpoint

        the_task = make_task(task)
        return LearnedController(default_checkpoint(spec, the_task.name), the_task)
    if spec.startswith("learned:"):
        from sb3_memret.controllers.learned import LearnedController

        path, _, query = spec.removeprefix("learned:").partition("?")
        if not path:
            raise ValueError(f"malformed learned controller {spec!r}; expected 'learned' or {_form('learned:')!r}")
        return LearnedController(path, make_task(task), **_options(spec, query, LEARNED_OPTIONS))
    if spec.startswith("openpi:"):
        host, port, options = parse_openpi_spec(spec)
        from sb3_memret.controllers.openpi import OpenPIController, ServerLimits

        chunk_len = options.pop("chunk_len", None)
        limits = ServerLimits(**{("infer_timeout" if k == "timeout" else k): v for k, v in options.items()})
        return OpenPIController(host, port, chunk_len=chunk_len, limits=limits,
                                task_template=make_task(task).prompt_template)
    if spec.startswith("lerobot:"):
        path, options = parse_lerobot_spec(spec)
        from sb3_memret.controllers.lerobot_pi05 import LeRobotPi05Controller

        return LeRobotPi05Controller(path, prompt_template=make_task(task).prompt_template, **options)
    raise ValueError(f"unknown controller {spec!r}; expected one of {list(CONTROLLER_SPECS)}")


def _form(prefix: str) -> str:
    """The accepted form (``CONTROLLER_SPECS``) that begins with ``prefix``."""
    return next(form for form in CONTROLLER_SPECS if form.startswith(prefix))


def parse_openpi_spec(spec: str) -> tuple[str, int, dict[str, Any]]:
    """``openpi://HOST:PORT[?k=v...]`` -> (host, port, options), or a ValueError naming the problem."""
    form = _form('openpi:')
    parts = urlsplit(spec)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme != "openpi" or not parts.hostname or port is None or parts.path or parts.fragment:
        raise ValueError(f"malformed openpi controller {spec!r}; expected {form!r}, e.g. 'openpi://localhost:8000'")
    return parts.hostname, port, _options(spec, parts.query, OPENPI_OPTIONS)


def parse_lerobot_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """``lerobot:PATH[?k=v...]`` -> (checkpoint path, options), or a ValueError naming the problem."""
    path, _, query = spec.removeprefix("lerobot:").partition("?")
    if not path:
        raise ValueError(f"malformed lerobot controller {spec!r}; expected {_form('lerobot:')!r}")
    return path, _options(spec, query, LEROBOT_OPTIONS)


def _options(spec: str, query: str, accepted: dict[str, Callable[[str], Any]]) -> dict[str, Any]:
    """Parse a ``k=v&k=v`` query, refusing unknown, repeated, empty or ill-typed values."""
    try:
        pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        pairs = [("", query)]
    options: dict[str, Any] = {}
    for key, value in pairs:
        if key not in accepted or key in options or not value:
            raise ValueError(f"bad option {key!r}={value!r} in controller {spec!r}; each of {sorted(accepted)} "
                             "may be given once, with a value")
        try:
            options[key] = accepted[key](value)
        except ValueError:
            raise ValueError(f"option {key}={value!r} in controller {spec!r} is not a valid "
                             f"{accepted[key].__name__}") from None
    return options


__all__ = ["CONTROLLER_SPECS", "make_controller", "parse_lerobot_spec", "parse_openpi_spec"]
