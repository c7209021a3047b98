"""Simulated tasks and the decision env. Light on purpose: importing the package registers only the
decision env's gymnasium id; ``import sb3_memret.tasks.drawer.drawer_cube`` registers DrawerCubeTakeOut-v1 with
ManiSkill (as importing a ManiSkill task module does), so constants such as the drawer's ``LAYERS``
load without ManiSkill or torch."""

import gymnasium

__all__ = ["RECALL_ENV_ID"]

RECALL_ENV_ID = "sb3_memret/DrawerRecall-v0"
if RECALL_ENV_ID not in gymnasium.registry:
    gymnasium.register(RECALL_ENV_ID, entry_point="sb3_memret.envs.recall:DrawerRecallEnv")
