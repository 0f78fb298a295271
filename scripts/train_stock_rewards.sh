#!/usr/bin/env bash
# Makes the shipped DREM checkpoints of ManiSkill's own tasks, rewards/<task>/drem.pt, as their
# model cards say: the stock scripted expert's demo (seed 1000), backward sampling with M=100,
# and the image-only model (these tasks have no F/T sensor: cameras base_camera + hand_camera)
# for 2000 iterations at 64 px; then the examination on held-out seeds 0-19, which sets DREM
# beside ManiSkill's normalized_dense where the task has one. Each stage resumes.
# The stages are scripts/train_default_rewards.sh's, without its separate image-only baseline.
#   bash scripts/train_stock_rewards.sh [TASK ...]   (default: PegInsertionSide-v1 PlugCharger-v1)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(PegInsertionSide-v1 PlugCharger-v1)
export M=${M:-100} ITERS=${ITERS:-2000} STEP_SCALE=${STEP_SCALE:-0} IMAGE_BASELINE=0 OMP_WAIT_POLICY=PASSIVE
exec bash scripts/train_default_rewards.sh "${tasks[@]}"
