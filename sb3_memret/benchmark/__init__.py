"""Benchmarks' own protocols with sb3-memret's agent as the policy: MIKASA-Robo-VLA's horizon splits through its
harness (``sb3-memret benchmark mikasa``)."""
