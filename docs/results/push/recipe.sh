#!/usr/bin/env bash
# Stop 21's USB checkpoint with the side phase and the push children (not shipped; docs/drem.md,
# "The side phase and the push children"). Made in three steps: stop 20's tree (the first two phases
# below without --side-depth/--push-children), then grown by resumes of a copy renamed to tree.h5.partial,
# first with --side-depth 8, then with --push-children 30 as well. One run of the sample command does the same.
set -euo pipefail
BIN=drem-maniskill
out=${OUT:-outputs/usb21}
$BIN record-expert --task USBInsertion-v1 --seed 1000 --descend-from 0.006 --out $out/expert
$BIN sample --expert $out/expert/expert.h5 --out $out/push/tree.h5 --num-children 500 --expert-step-scale 4 \
  --outward-depth 10 --face-depth 8 --side-depth 8 --push-children 30
$BIN train-reward --dataset $out/push/tree.h5 --out $out/push/reward --preset quick --iterations 20000 --threads 1
$BIN examine --task USBInsertion-v1 --checkpoint $out/push/reward/drem.pt --out $out/push/examination --episodes 20
# SAC, as stop 20's runs (seeds 0 and 1):
for seed in 0 1; do
  $BIN train-policy --task USBInsertion-v1 --reward drem --seed $seed --steps 40000 --preset state --no-bf16 \
    --no-overlap-env --eval-episodes 10 --threads 1 --reward-checkpoint $out/push/reward/drem.pt \
    --out $out/sac/USBInsertion-v1/drem/seed$seed
done
