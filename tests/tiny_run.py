"""The smallest real training run the tests make: rounds of 16 decisions, episodes of 48 control steps (6
decisions), so a run on the real simulator takes seconds."""

TINY = """sb3_memret/DrawerRecall-v0:
  n_timesteps: 32
  n_envs: 1
  n_steps: 16
  batch_size: 8
  n_epochs: 2
  env_kwargs:
    max_control_steps: 48
"""
