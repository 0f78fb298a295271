#!/usr/bin/env bash
# Makes the shipped reward checkpoints in rewards/<task>/ (the commands in each model card).
# Scale is set for this 2-core CPU machine; see rewards/<task>/MODEL_CARD.md for how it
# differs from the paper (M=500, 20k iterations at 128 px on a GPU).
#   bash scripts/train_default_rewards.sh [TASK ...]    (default: both tasks)
# Each stage resumes after an interruption; outputs go to outputs/default/<task>/.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
BIN=.venv/bin/drem-maniskill
M=${M:-200}
ITERS=${ITERS:-3000}
for T in "${@:-PegInHole-v1 USBInsertion-v1}"; do
  for task in $T; do
    out=outputs/default/$task
    [ -f "$out/expert/expert.h5" ] || $BIN record-expert --task "$task" --seed 1000 --episodes 1 --out "$out/expert"
    [ -f "$out/tree.h5" ] || $BIN sample --expert "$out/expert/expert.h5" --out "$out/tree.h5" --num-children "$M"
    $BIN train-reward --dataset "$out/tree.h5" --out "$out/reward" --preset quick --iterations "$ITERS"
    $BIN train-reward --dataset "$out/tree.h5" --out "$out/reward_image" --preset quick --iterations "$ITERS" --modalities fixed wrist
  done
done
