"""MIKASA-Robo-VLA's TraceShape tasks: a path a red cube traced once, carried round again with a green cube."""
