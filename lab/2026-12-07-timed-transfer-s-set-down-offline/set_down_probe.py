"""Does the shipped camera controller predict TimedTransferEasy's set-down on the expert's own frames? Per decision
frame of expert episodes told the true count, the hand's height command (the action's z entry, summed over the chunk:
the set-down lowers the cube onto the red disc) and the gripper's (its last entry: > 0 opens) in the expert's label
chunk and in the policy's predicted chunk, grouped by the count the prompt states.

    .venv/bin/python lab/2026-12-07-timed-transfer-s-set-down-offline/set_down_probe.py CHECKPOINT DATASET...
"""

from __future__ import annotations

import argparse
import re

import numpy as np
import torch

from sb3_memret.controllers.harness_proprio import reads_harness_proprio
from sb3_memret.controllers.learned import LearnedPolicy
from sb3_memret.controllers.learned.processing import LearnedPolicyProcessor, PromptTokenizer
from sb3_memret.stage1.datasets import load_task_demonstrations
from sb3_memret.stage1.finetune import camera_inputs

TASK = "TimedTransferEasy-VLA-v0"
COUNT = re.compile(r"the lamp turned green (\d+) steps ago")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("datasets", nargs="+")
    args = parser.parse_args()
    policy = LearnedPolicy.from_pretrained(args.checkpoint).eval()
    demos, _ = load_task_demonstrations({TASK: args.datasets})
    if reads_harness_proprio(policy.config.state_names):
        demos = demos.with_harness_proprio()
    prompts = [demos.tasks[i] for i in demos.task_ids]
    counts = np.array([int(m[1]) if (m := COUNT.search(p)) else -1 for p in prompts])
    told = np.flatnonzero(counts >= 0)
    tokenizer = PromptTokenizer()
    processor = LearnedPolicyProcessor(policy.config, tokenizer=tokenizer)
    features = camera_inputs(policy, processor, {k: v.take(told) for k, v in demos.images.items()},
                             policy.config.image_features, cache=False)
    cameras = [processor.camera(f) if policy.trunk is None else f.float() for f in features]
    with torch.no_grad():
        encoded = policy.encode_prompts(*tokenizer(demos.tasks))[torch.from_numpy(demos.task_ids[told])]
        states = processor.state(demos.states[told], processor.state_columns(demos.state_names, "the datasets"))
        predicted = policy(states, encoded, cameras).numpy()
    targets, pad = demos.targets(policy.config.chunk_len)
    live = ~pad[told]
    expert_dz = (targets[told][..., 2] * live).sum(1)
    policy_dz = (predicted[..., 2] * live).sum(1)
    opens_expert = (np.where(live, targets[told][..., -1], -1) > 0).any(1)
    opens_policy = (np.where(live, predicted[..., -1], -1) > 0).any(1)
    print(f"{len(told)} decision frames told the count, of {len(set(demos.episodes[told]))} episodes\n")
    print("| count stated | frames | expert's chunk: z summed (mean) | policy's | expert's opens the gripper | "
          "policy's |\n|---|---|---|---|---|---|")
    for low in range(0, 110, 10):
        rows = (counts[told] >= low) & (counts[told] < low + 10)
        if rows.any():
            print(f"| {low}-{low + 9} | {int(rows.sum())} | {expert_dz[rows].mean():+.2f} | "
                  f"{policy_dz[rows].mean():+.2f} | {int(opens_expert[rows].sum())} | "
                  f"{int(opens_policy[rows].sum())} |")
    late = counts[told] >= 90
    print("\nframes at counts 90 and over (count, expert's z, policy's z):")
    for i in np.flatnonzero(late):
        print(f"  {counts[told][i]} {expert_dz[i]:+.2f} {policy_dz[i]:+.2f}")


if __name__ == "__main__":
    main()
