"""MIKASA-Robo-VLA memory tasks (the ``mikasa-robo-suite`` package) as sb3-memret tasks, and the parts a task of
your own reuses:

- ``MikasaCueTask``: the base class of a task whose memory is one word about a cue shown once (its class
  attributes are documented on it), with ``CueWriter`` (its writer) and ``EVAL_SEED`` (MIKASA's first evaluation
  seed);
- readers, one base-camera frame in, the cue's word out: ``read_cue_colour`` (``COLOUR_NAMES``, MIKASA's colour
  order) and ``read_cue_shape`` (``SHAPE_NAMES``);
- controller views, wrappers that cut MIKASA's observation to joints, hand, cameras and an object detector:
  ``DetectorObservation`` (any objects), ``ControllerObservation`` (RememberColor's cubes),
  ``ShapeControllerObservation`` (RememberShape's objects);
- experts: ``ScriptedTouchController`` (touches the object its prompt's word names; ``TouchGains`` its motion).

The names import on first use: the package itself imports nothing heavy.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "CueWriter": "cue_task", "EVAL_SEED": "cue_task", "MikasaCueTask": "cue_task",
    "COLOUR_NAMES": "perception", "ControllerObservation": "perception", "DetectorObservation": "perception",
    "read_cue_colour": "perception",
    "SHAPE_NAMES": "shape_perception", "ShapeControllerObservation": "shape_perception",
    "read_cue_shape": "shape_perception",
    "ScriptedTouchController": "expert", "TouchGains": "expert",
}


def __getattr__(name: str) -> Any:
    """``name`` from the module that defines it (PEP 562), imported on first use."""
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])


__all__ = sorted(_EXPORTS)
