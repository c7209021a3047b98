"""The ShellGame family: which cup hides the ball (Touch, Push), which colour is under each cup (ColorLampTouch),
both tracked through a shuffle (the Shuffle tasks). Its parts: the YCB mug it needs (``assets``), the five envs
(``variants``), what the base camera sees (``tracking``), the writer (``writer``), the controllers' views (``views``),
the experts (``experts``) and the tasks (``task``, whose docstring gives the episode, its randomisations and what
was and was not calibrated).

The names import on first use, from the module that defines them.
"""

from __future__ import annotations

from sb3_memret.common.lazy import lazy_exports

_EXPORTS = {
    "CameraFrame": "tracking", "CupGains": "experts", "CupObservation": "views", "CupPushController": "experts",
    "CupTouchController": "experts", "CupWriter": "writer", "FACT_TEMPLATE": "variants", "LAMP_COLOURS": "variants",
    "LampCupObservation": "views", "MUG_FILES": "assets", "SIDES": "variants", "ShellGameColorLampTask": "task",
    "ShellGameTask": "task", "VARIANTS": "variants", "YCB_DIR": "assets", "ball_mask": "tracking",
    "ball_on_table": "tracking", "cups_on_table": "tracking", "follow": "tracking", "least_moves": "tracking",
    "left_to_right": "views", "maniskill_asset_dir": "assets", "shell_game_task": "task", "swap_turn": "tracking",
    "table_point": "tracking", "ycb_mug_missing": "assets",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())

__all__ = sorted(_EXPORTS)
