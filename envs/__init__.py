"""Simulated tasks; importing this package registers them with ManiSkill and gymnasium."""

import gymnasium

from sb3_memret.envs.cabinet import LAYERS, CabinetLayout
from sb3_memret.envs.drawer_cube import DrawerCubeState, DrawerCubeTakeOutEnv

__all__ = ["RECALL_ENV_ID", "LAYERS", "CabinetLayout", "DrawerCubeState", "DrawerCubeTakeOutEnv"]

RECALL_ENV_ID = "sb3_memret/DrawerRecall-v0"
if RECALL_ENV_ID not in gymnasium.registry:
    gymnasium.register(RECALL_ENV_ID, entry_point="sb3_memret.envs.recall:DrawerRecallEnv")
