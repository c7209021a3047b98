"""MIKASA-Robo-VLA memory tasks (the ``mikasa-robo-suite`` package) as sb3-memret tasks."""
