#!/bin/bash
# One camera controller across TASKS (or one task's own, on the same chunks), from what scripts/record_task_demos.sh
# recorded into DEMOS: every finished chunk of each task is a dataset, named with its task (finetune --tasks), and the
# policy lands in OUT. DEMOS may list several roots, comma-separated (the experts' demonstrations and a DAgger
# round's): each must hold finished chunks of every task, except a root marked optional with a trailing '?' (more
# episodes of some tasks only), whose tasks without chunks are skipped. An unfinished finetune in OUT (stopped or
# crashed: OUT/training_state.pt) goes on where it stopped (finetune --resume; refused if the data or options differ);
# a finished one (OUT/model.safetensors) is kept when OUT/finetune_inputs.txt records the same chunks and options, and
# refused otherwise, so a make target that stopped after it runs again without training it twice.
# Usage: scripts/finetune_task_demos.sh DEMOS[,DEMOS...] OUT TASK[,TASK...] [finetune options...]
#   e.g. scripts/finetune_task_demos.sh runs/multitask runs/multitask/policy \
#          RememberColor3-VLA-v0,RememberShape3-VLA-v0 --set training.steps=4000
#        scripts/finetune_task_demos.sh 'runs/multitask,runs/more-shapes?' runs/multitask/policy \
#          RememberColor3-VLA-v0,RememberShape3-VLA-v0
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 3 ]; then
  echo "usage: $0 DEMOS[,DEMOS...] OUT TASK[,TASK...] [finetune options...]" >&2
  exit 2
fi
IFS=, read -r -a roots <<< "$1"
out=$2
IFS=, read -r -a wanted <<< "$3"
shift 3
datasets=() tasks=()
for task in "${wanted[@]}"; do
  before=${#datasets[@]}
  for spec in "${roots[@]}"; do
    root=${spec%\?} found=0
    for done in "$root/$task"/chunk*.done; do
      [ -e "$done" ] || continue
      datasets+=("${done%.done}") tasks+=("$task") found=1
    done
    if [ $found -eq 0 ] && [ "$root" = "$spec" ]; then
      echo "no finished chunks of $task under $root: record them with scripts/record_task_demos.sh $root EPISODES $task" >&2
      exit 2
    fi
  done
  if [ ${#datasets[@]} -eq "$before" ]; then
    echo "no finished chunks of $task under any of ${roots[*]}" >&2
    exit 2
  fi
done
if [ ${#wanted[@]} -eq 1 ]; then  # one task's chunks: a per-task policy, on the same data as a multi-task one
  task_args=(--task "${wanted[0]}")
else
  task_args=(--tasks "$(IFS=,; echo "${tasks[*]}")")
fi
inputs=$(printf '%s\n' "${datasets[@]}" "${task_args[@]}" "$@")
record="$out/finetune_inputs.txt"
resume=()
if [ -f "$out/training_state.pt" ]; then
  resume=(--resume)
  echo "resuming the unfinished finetune in $out"
elif [ -f "$out/model.safetensors" ]; then
  if [ -f "$record" ] && [ "$(cat "$record")" = "$inputs" ]; then
    echo "$out already holds this finetune (the same chunks and options): kept"
    exit 0
  fi
  echo "$out holds a policy finetuned on other chunks or options (its record: $record); delete the folder to" \
    "finetune again" >&2
  exit 2
fi
mkdir -p "$out"
printf '%s\n' "$inputs" > "$record"
echo "finetuning on ${#datasets[@]} chunks of ${#wanted[@]} task(s) from ${roots[*]}"
.venv/bin/sb3-memret finetune "${datasets[@]}" "${task_args[@]}" --out "$out" "${resume[@]}" "$@"
