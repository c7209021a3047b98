"""What the MIKASA test modules share: the skip reason when the package is missing, and the leak check."""

#: the first of MIKASA's evaluation seeds (4242424242 + i) that the protocol tests play: the suite's budget; the
#: figures over all 50 come from ``lab/2026-11-23-the-memory-learner-on-the-scripted-experts/mikasa_probe.py --episodes 50`` (README, Tasks)
PROTOCOL_SEEDS = 12
#: the first of them on which a condition that must always fail (no fact, a fact missing) is played: any one success
#: there fails the test, so a sample checks it as surely, at a third of the cost
FAILING_SEEDS = 4

MIKASA_MISSING = ("mikasa-robo-suite is not installed "
                  "(pip install --no-deps --ignore-requires-python mikasa-robo-suite==1.0.0)")


def leaked_keys(tree, forbidden, prefix=""):
    """The paths (``/extra/oracle_info``) of a nested observation whose names contain a forbidden word."""
    out = []
    if isinstance(tree, dict):
        for k, v in tree.items():
            path = f"{prefix}/{k}"
            out += [path] if any(bad in path for bad in forbidden) else []
            out += leaked_keys(v, forbidden, path)
    return out
