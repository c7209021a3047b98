"""Frozen low-level controllers behind one interface (``base``): the project's learned controller
(``learned``), π0.5 served by openpi (``openpi``) or run in-process through LeRobot (``lerobot_pi05``). A task's
scripted expert lives with its task; ``sb3_memret.controller_specs`` builds any of them from a CLI
``--controller`` value."""

from sb3_memret.controllers.base import ControllerSpec, FrozenController

__all__ = ["ControllerSpec", "FrozenController"]
