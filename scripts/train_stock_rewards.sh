#!/usr/bin/env bash
# Makes the shipped DREM checkpoints of ManiSkill's own tasks, rewards/<task>/drem.pt, as their
# model cards say: the stock scripted expert's demo (seed 1000), backward sampling with M=100,
# and the image-only model (these tasks have no F/T sensor: cameras base_camera + hand_camera)
# for 2000 iterations at 64 px; then the examination on held-out seeds 0-19, which sets DREM
# beside ManiSkill's normalized_dense where the task has one. Each stage resumes.
#   bash scripts/train_stock_rewards.sh [TASK ...]   (default: PegInsertionSide-v1 PlugCharger-v1)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
BIN=.venv/bin/drem-maniskill
M=${M:-100}
ITERS=${ITERS:-2000}
EPISODES=${EPISODES:-20}
export OMP_WAIT_POLICY=PASSIVE
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(PegInsertionSide-v1 PlugCharger-v1)
for task in "${tasks[@]}"; do
  out=outputs/default/$task
  [ -f "$out/expert/expert.h5" ] || $BIN record-expert --task "$task" --seed 1000 --episodes 1 --out "$out/expert"
  [ -f "$out/tree.h5" ] || $BIN sample --expert "$out/expert/expert.h5" --out "$out/tree.h5" --num-children "$M"
  $BIN train-reward --dataset "$out/tree.h5" --out "$out/reward" --preset quick --iterations "$ITERS" --threads 1
  $BIN examine --task "$task" --checkpoint "$out/reward/drem.pt" --out "$out/examination" --episodes "$EPISODES"
  mkdir -p "rewards/$task"
  cp "$out/reward/drem.pt" "rewards/$task/drem.pt"
  cp "$out/examination/quality.json" "rewards/$task/quality.json"
  cp "$out/examination/examination.png" "rewards/$task/examination.png"
done
