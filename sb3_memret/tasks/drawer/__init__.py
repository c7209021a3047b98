"""The drawer, the seed's task, in its own room: the task (``task``), what its writer reads and writes
(``writer``) and the decoys its bank is seeded with (``seeding``). The simulated cabinet and its cube are
``sb3_memret.tasks.drawer.drawer_cube`` (DrawerCubeTakeOut-v1)."""

from sb3_memret.tasks.drawer.task import ENV_ID, DrawerTask
from sb3_memret.tasks.drawer.writer import DrawerWriter

__all__ = ["DrawerTask", "DrawerWriter", "ENV_ID"]
