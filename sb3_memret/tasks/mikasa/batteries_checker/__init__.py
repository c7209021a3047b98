"""MIKASA-Robo-VLA's BatteriesChecker Easy/Hard 3/6: the checklist of batteries tested, its writer and its expert."""
