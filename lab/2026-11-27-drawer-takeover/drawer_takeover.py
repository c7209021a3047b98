"""Can the drawer's scripted expert recover from the states a learned controller fails in?

DAgger relabels the states a learner reaches with the expert's actions; the labels help only where the expert,
put in such a state, would itself succeed. Plays the camera controller (or another learned one) with the oracle
prompt on one layer at development seeds; for each episode it fails, replays it to several points (a share of its
decisions) and hands over to the scripted expert from there, which reads its phase from what it observes. Prints,
per failed episode, how it ended (privileged state, for the diagnosis only: the target drawer's opening, grasped,
the target's layer, the hand's distance to it) and whether the expert recovered from each hand-over point.

    python lab/2026-11-27-drawer-takeover/drawer_takeover.py --layer 3 --episodes 30 --seed 2000000
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_memret.controller_specs import make_controller
from sb3_memret.common.obs_trees import stack_obs
from sb3_memret.physics.backends import TaskRunner
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.evaluation.rollout import task_env_kwargs
from sb3_memret.tasks import make_task


def play(runner: TaskRunner, controller, prompt: str, seed: int, layer: int, replan_every: int,
         prefix: list[np.ndarray] | None = None) -> tuple[bool, list[np.ndarray], object]:
    """An episode at ``seed``: ``prefix``'s chunks replayed first, then ``controller`` until the episode ends. Returns
    success, every executed chunk, and the last frame."""
    options = {"target_layer": layer}
    frame = runner.replay(seed, options, prefix) if prefix else runner.reset(seed, options)
    controller.reset([seed])
    chunks = list(prefix or [])
    while not (frame.terminated or frame.truncated or frame.success):
        chunk = controller.act(stack_obs([frame.obs]), [prompt])[0][:replan_every]
        chunks.append(chunk)
        frame = runner.execute(chunk)
    return frame.success, chunks, frame


def ending(frame, layer: int) -> str:
    """How an episode ended, from the privileged state: the drawer, the grasp, where the target is."""
    state = frame.state
    opening = float(state.drawer_qpos[0, layer - 1])
    reach = float(np.linalg.norm(state.eef_pos[0] - state.target_pos[0]))
    return (f"drawer {layer} open {100 * opening:4.1f} cm, grasped {bool(state.grasped[0])}, target in layer "
            f"{int(state.target_in_layer[0])}, hand {100 * reach:4.1f} cm from it")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controller", default="learned")
    parser.add_argument("--layer", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--seed", type=int, default=2_000_000, help="first development seed (never protocol seeds)")
    parser.add_argument("--handover", default="0.25,0.5,0.75", help="shares of the failed episode's decisions")
    parser.add_argument("--replan-every", type=int, default=8)
    args = parser.parse_args()

    task = make_task("drawer")
    learner, expert = make_controller(args.controller, task), make_controller("scripted", task)
    runner = TaskRunner(task_env_kwargs(learner, "cpu", task), task.max_control_steps, task)
    shares = [float(s) for s in args.handover.split(",")]
    failed = recovered = 0
    counts = np.zeros(len(shares), dtype=int)
    try:
        for seed in range(args.seed, args.seed + args.episodes):
            frame = runner.reset(seed, {"target_layer": args.layer})
            prompt = build_prompt(task.instruction(task.episode(frame)), task.oracle_facts(task.episode(frame)),
                                  learner.spec.prompt_template)
            success, chunks, last = play(runner, learner, prompt, seed, args.layer, args.replan_every)
            if success:
                print(f"seed {seed}: learner succeeded in {len(chunks)} decisions", flush=True)
                continue
            failed += 1
            outcomes = []
            for k, share in enumerate(shares):
                cut = max(1, int(share * len(chunks)))
                won, played, _ = play(runner, expert, prompt, seed, args.layer, args.replan_every, chunks[:cut])
                counts[k] += won
                outcomes.append(f"{share:.0%} (decision {cut}, expert played {len(played) - cut}): "
                                f"{'recovered' if won else 'failed'}")
            recovered += any("recovered" in o for o in outcomes)
            print(f"seed {seed}: learner FAILED after {len(chunks)} decisions ({ending(last, args.layer)}); "
                  "expert from "
                  + ", ".join(outcomes), flush=True)
    finally:
        runner.close()
    print(f"\nlayer {args.layer}: learner failed {failed}/{args.episodes}; the expert recovered from at least one "
          f"hand-over point in {recovered}/{failed}; per point: "
          + ", ".join(f"{s:.0%} {c}/{failed}" for s, c in zip(shares, counts)))


if __name__ == "__main__":
    main()
