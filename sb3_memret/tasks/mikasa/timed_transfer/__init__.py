"""MIKASA-Robo-VLA's TimedTransfer tasks: the time since a lamp turned green, a fact that carries a time."""
