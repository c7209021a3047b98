"""What the MIKASA test modules share: the skip reason when the package is missing, the leak check, a camera expert's
observation and its harness episodes."""

import numpy as np

#: the first of the development seeds (5000 + i: ``Task.development_seeds``) that the tests over many episodes play,
#: the suite's budget; MIKASA's evaluation seeds (4242424242 + i) are its test set, which no test plays
DEV_SEEDS = 12
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


def harness_obs(tcp, gap, seen):
    """One env's observation as the policy-side view gives a camera expert: the TCP's pose (a position, pointing
    down, or a 7-D pose), the fingers ``gap`` apart, and for the base camera's "image" whatever the test's stand-in
    reader takes."""
    tcp = np.asarray(tcp, dtype=np.float64)
    pose = tcp if tcp.size == 7 else np.array([*tcp, 0, 1, 0, 0])
    return {"extra": {"tcp_pose": pose[None]}, "agent": {"qpos": np.array([[*[np.nan] * 7, gap / 2, gap / 2]])},
            "sensor_data": {"base_camera": {"rgb": [seen]}}}


def camera_expert_cells(env_id, out):
    """Play ``env_id``'s first development episode under oracle and written with ``scripted-camera`` through
    MIKASA's harness (the simulator guard on), into ``out``: the run's results and the task's cells."""
    from sb3_memret.benchmark import runner

    protocol = runner.Protocol(seed_set="dev", episodes=1, controller="scripted-camera")
    results = runner.run_benchmark(runner.plan(protocol, ["oracle", "written"], env_ids=[env_id]), out, workers=1)
    return results, results["tasks"][env_id]["conditions"]
