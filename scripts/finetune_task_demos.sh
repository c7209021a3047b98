#!/bin/bash
# One camera controller across the tasks that scripts/record_task_demos.sh recorded into DEMOS: every finished chunk
# of every task folder is a dataset, named with its task (finetune --tasks), and the policy lands in OUT.
# Usage: scripts/finetune_task_demos.sh DEMOS OUT [finetune options...]
#   e.g. scripts/finetune_task_demos.sh runs/multitask runs/multitask/policy --steps 4000
set -euo pipefail
cd "$(dirname "$0")/.."
demos=$1 out=$2
shift 2
datasets=() tasks=()
for folder in "$demos"/*/; do
  task=$(basename "$folder")
  for done in "$folder"chunk*.done; do
    [ -e "$done" ] || continue
    datasets+=("${done%.done}") tasks+=("$task")
  done
done
if [ ${#datasets[@]} -eq 0 ]; then
  echo "no finished chunks under $demos: record them with scripts/record_task_demos.sh $demos EPISODES TASK..." >&2
  exit 2
fi
.venv/bin/sb3-memret finetune "${datasets[@]}" --tasks "$(IFS=,; echo "${tasks[*]}")" --out "$out" "$@"
