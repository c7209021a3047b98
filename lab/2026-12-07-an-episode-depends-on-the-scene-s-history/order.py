"""Does an episode depend on the episodes its benchmark worker played before, and does a scene built anew at every
reset end it? Usage: python order.py ENV_ID CONDITION BEFORE_SEEDS TARGET_SEED default|fresh (BEFORE_SEEDS a comma
list, or "" for the target alone in a new process); prints each episode's success, return, steps as one JSON line.
Written before `fresh_scenes` was a protocol setting: it sets ManiSkill's reconfiguration_freq by hand."""
import sys, json
from sb3_memret.benchmark.runner import Protocol, Unit, _Worker
from sb3_memret.common.workers import torch_threads

env_id, cond = sys.argv[1], sys.argv[2]
before = [int(s) for s in sys.argv[3].split(",")] if sys.argv[3] else []
target = int(sys.argv[4]); fresh = sys.argv[5] == "fresh"
protocol = Protocol(episodes=50, controller="scripted")
worker = _Worker(protocol, None)
out = []
with torch_threads(1):
    for seed in before + [target]:
        worker.agent(env_id, cond)
        if fresh:  # every reset builds the scene anew
            worker.env.unwrapped.reconfiguration_freq = 1
            worker.env.unwrapped._reconfig_counter = 0
        r = worker.play(Unit(env_id, cond, seed))
        out.append((seed, r.get("success"), repr(r.get("return")), r.get("steps"), r.get("error")))
print(json.dumps({"before": before, "fresh": fresh, "episodes": out}))
