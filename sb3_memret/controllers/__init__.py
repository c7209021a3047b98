"""Frozen low-level controllers behind one interface, and a factory for CLI specs."""

from sb3_memret.controllers.base import ControllerSpec, FrozenController
from sb3_memret.controllers.scripted import ScriptedDrawerController

CONTROLLER_SPECS = ("scripted",)


def make_controller(spec: str) -> FrozenController:
    """Build the controller a CLI ``--controller`` value names, or raise a ValueError listing the options."""
    if spec == "scripted":
        return ScriptedDrawerController()
    raise ValueError(f"unknown controller {spec!r}; expected one of {list(CONTROLLER_SPECS)}")


__all__ = ["CONTROLLER_SPECS", "ControllerSpec", "FrozenController", "ScriptedDrawerController", "make_controller"]
