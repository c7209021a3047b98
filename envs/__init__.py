"""Simulated tasks; importing this package registers them with ManiSkill and gymnasium."""

from sb3_memret.envs.cabinet import LAYERS, CabinetLayout
from sb3_memret.envs.drawer_cube import DrawerCubeState, DrawerCubeTakeOutEnv

__all__ = ["LAYERS", "CabinetLayout", "DrawerCubeState", "DrawerCubeTakeOutEnv"]
