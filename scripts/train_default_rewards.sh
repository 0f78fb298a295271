#!/usr/bin/env bash
# Makes the shipped reward checkpoints rewards/<task>/drem.pt and the image-only baseline
# rewards/<task>/drem_image.pt (same tree, --modalities fixed wrist), as their model cards say:
# the scripted expert's demo (seed 1000), a tree of M=500 children per depth whose random
# actions follow the expert's own step (STEP_SCALE times it; docs/drem.md), continued OUTWARD
# depths past the start region away from the expert's path (not in the paper; docs/drem.md), 20k iterations at
# 64 px (the paper: 128 px on a GPU), the examination on held-out seeds 0-19. Each stage resumes
# after an interruption: rerun the same command.
#   bash scripts/train_default_rewards.sh [TASK ...]      (default: every task of drem_maniskill.envs.TASKS)
# M, ITERS, STEP_SCALE (0: the paper's fixed action range), OUTWARD (0: the paper's tree) and
# EPISODES (held-out examination seeds) override the scale, WORKERS the sampler's processes; IMAGE_BASELINE=0 skips
# the image-only baseline (scripts/train_stock_rewards.sh, whose tasks have no F/T anyway).
# The expert descends DESCENT metres per step inside the hole: 0.002 on PegInHole-v1 (the shipped
# checkpoint since stop 14, docs/drem.md), 0.001 from 6 mm above the port on USBInsertion-v1 (GT, the
# shipped checkpoints since stop 29), the expert's default 0.005 elsewhere. FACE depths of the
# face phase (lineages sliding the part over the socket's face; not in the paper, docs/drem.md):
# 8 on USBInsertion-v1, 0 elsewhere. USBInsertion-v1 also gets GT's goal presses, side, push and turn
# phases (docs/drem.md, "The goal presses", "The side phase and the push children", "The turn phase").
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
BIN=.venv/bin/drem-maniskill
M=${M:-500}
ITERS=${ITERS:-20000}
STEP_SCALE=${STEP_SCALE:-4}
OUTWARD=${OUTWARD:-10}
EPISODES=${EPISODES:-20}
IMAGE_BASELINE=${IMAGE_BASELINE:-1}
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || mapfile -t tasks < <(.venv/bin/python -c "from drem_maniskill.envs import TASKS; print(*TASKS, sep='\n')")
for task in "${tasks[@]}"; do
  out=outputs/default/$task
  expert_extra=() sample_extra=()
  case $task in
    PegInHole-v1) descent=${DESCENT:-0.002} face=${FACE:-0} ;;
    USBInsertion-v1) descent=${DESCENT:-0.001} face=${FACE:-8} expert_extra=(--descend-from 0.006)
      sample_extra=(--goal-presses 500 --side-depth 8 --push-children 30 --turn-depth 24 --turn-children 16) ;;
    *) descent=${DESCENT:-0.005} face=${FACE:-0} ;;
  esac
  [ -f "$out/expert/expert.h5" ] || $BIN record-expert --task "$task" --seed 1000 --episodes 1 --out "$out/expert" --descent-step "$descent" "${expert_extra[@]}"
  [ -f "$out/tree.h5" ] || $BIN sample --expert "$out/expert/expert.h5" --out "$out/tree.h5" --num-children "$M" --expert-step-scale "$STEP_SCALE" --outward-depth "$OUTWARD" --face-depth "$face" "${sample_extra[@]}" --workers "${WORKERS:-1}"
  $BIN train-reward --dataset "$out/tree.h5" --out "$out/reward" --preset quick --iterations "$ITERS" --threads 1
  # Quality on held-out seeds 0-19 (the expert demo used seed 1000).
  $BIN examine --task "$task" --checkpoint "$out/reward/drem.pt" --out "$out/examination" --episodes "$EPISODES"
  mkdir -p "rewards/$task"
  cp "$out/reward/drem.pt" "rewards/$task/drem.pt"
  cp "$out/examination/quality.json" "rewards/$task/quality.json"
  cp "$out/examination/examination.png" "rewards/$task/examination.png"
  # Thresholds of the drem-guarded experiment (docs/drem.md; not in the paper).
  $BIN calibrate-support --checkpoint "$out/reward/drem.pt" --dataset "$out/tree.h5" --out "rewards/$task/support.json"
  [ "$IMAGE_BASELINE" = 1 ] || continue
  # The paper's "Image learned" baseline: the same model and tree without the F/T input.
  $BIN train-reward --dataset "$out/tree.h5" --out "$out/reward_image" --preset quick --iterations "$ITERS" --threads 1 --modalities fixed wrist
  $BIN examine --task "$task" --checkpoint "$out/reward_image/drem.pt" --out "$out/examination_image" --episodes "$EPISODES"
  cp "$out/reward_image/drem.pt" "rewards/$task/drem_image.pt"
  cp "$out/examination_image/quality.json" "rewards/$task/quality_image.json"
  cp "$out/examination_image/examination.png" "rewards/$task/examination_image.png"
done
