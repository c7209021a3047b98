#!/bin/bash
# Expert demonstrations of MIKASA tasks for one camera controller across them, in chunks of 50 episodes, resumable: a
# finished chunk leaves OUT/TASK/chunkN.done, and a rerun records only the missing ones. FRAMES=decisions (the
# default) keeps the decision frames with their chunks of labels, the cameras rendering only there (a third of the
# CPU an episode of every frame costs, and RememberColor3's controller as good: lab/2026-11-28-one-camera-controller-across-tasks-the-pilot); FRAMES=every keeps
# every control step. One finetune takes chunks of one kind only.
# JOBS=N records N chunks at a time (default 1), each chunk held by one recorder (OUT/TASK/chunkN.lock, a lock the
# system releases when its recorder ends however it ends), so recorders on the same OUT never record a chunk twice.
# A DAgger round: LEARNER=learned:PATH has that policy act while the expert labels every frame; give it seeds of its
# own with SEED (chunk i starts at SEED + 50 i; default 100000, the expert's demonstrations). MAX_STEPS=N ends each
# episode after N control steps (demos --max-steps; default the task's own limit). PROMPT_MIX=KIND=SHARE,... sets the
# prompt kinds' shares (demos --prompt-mix; default its own).
# Usage: [FRAMES=decisions|every] [LEARNER=learned:PATH] [SEED=N] [MAX_STEPS=N] [PROMPT_MIX=...] [JOBS=N] scripts/record_task_demos.sh OUT EPISODES_PER_TASK TASK...
#   e.g. scripts/record_task_demos.sh runs/multitask 400 RememberColor3-VLA-v0 RememberShape3-VLA-v0
#        LEARNER=learned:runs/multitask/policy SEED=100400 scripts/record_task_demos.sh runs/multitask-dagger 150 \
#          RememberColor3-VLA-v0 RememberShape3-VLA-v0
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 3 ]; then
  echo "usage: [FRAMES=decisions|every] [LEARNER=learned:PATH] [SEED=N] [MAX_STEPS=N] [PROMPT_MIX=...] [JOBS=N] $0 OUT EPISODES_PER_TASK TASK..." >&2
  exit 2
fi
out=$1 episodes=$2
shift 2
chunk=50 first_seed=${SEED:-100000}
learner=()
[ -n "${LEARNER:-}" ] && learner=(--learner "$LEARNER")
limit=()
[ -n "${MAX_STEPS:-}" ] && limit=(--max-steps "$MAX_STEPS")
mix=()
[ -n "${PROMPT_MIX:-}" ] && mix=(--prompt-mix "$PROMPT_MIX")
# chunk i of every task before chunk i + 1 of any, so a recording stopped early leaves the tasks balanced
recorder() {
  for ((i = 0; i * chunk < episodes; i++)); do
    for task in "$@"; do
      mkdir -p "$out/$task"
      dest=$out/$task/chunk$i
      [ -f "$dest.done" ] && continue
      exec 9> "$dest.lock"
      if ! flock -n 9 || [ -f "$dest.done" ]; then  # another recorder holds it, or has just finished it
        exec 9>&-
        continue
      fi
      rm -rf "$dest"
      .venv/bin/sb3-memret demos --task "$task" --episodes "$chunk" --seed $((first_seed + chunk * i)) \
        --frames "${FRAMES:-decisions}" "${learner[@]}" "${limit[@]}" "${mix[@]}" --no-progress --out "$dest" > "$dest.log" 2>&1
      touch "$dest.done"
      exec 9>&-
    done
  done
}
pids=()
for ((w = 0; w < ${JOBS:-1}; w++)); do
  recorder "$@" &
  pids+=($!)
done
status=0
for pid in "${pids[@]}"; do
  wait "$pid" || status=1
done
exit $status
