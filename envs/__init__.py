"""The decision env: retrieval decisions over a bounded language memory for a frozen controller (``vec_env``, N
envs; ``recall``, one gymnasium env), each env's memory (``recall_memory``) and its configs (``configs``). Light on
purpose: importing the package registers only the decision env's gymnasium id."""

import gymnasium

__all__ = ["RECALL_ENV_ID"]

RECALL_ENV_ID = "sb3_memret/DrawerRecall-v0"
if RECALL_ENV_ID not in gymnasium.registry:
    gymnasium.register(RECALL_ENV_ID, entry_point="sb3_memret.envs.recall:DrawerRecallEnv")
