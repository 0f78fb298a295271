#!/usr/bin/env bash
# Stop 22's, 23's and 27's USB candidates G, G2, GF and GT (not shipped; docs/drem.md, "The goal presses"): a demo that descends
# 1 mm a step from DESCEND_FROM above the opening (G: 0.006, G2: 0.002), stop 16's recipe otherwise (M = 500,
# x4 actions, 10 outward depths, face 8), plus 500 goal presses; 20,000 iterations at 64 px; the examination;
# SAC as stop 20's and 21's runs.
set -euo pipefail
BIN=drem-maniskill
name=${NAME:-G}
# GF (stop 23): G's demo, with the side phase and the push children, sampled with the fixed face and side phases
# (docs/drem.md, "Lineages caught in the opening"). G and G2 were sampled before that fix: rerun now, their face
# phases come out as GF's does.
extra=""
# GT (stop 27): GF plus the turn phase (docs/drem.md, "The turn phase"), 24 depths of 16 children; sampled by growing a
# copy of GF's finished tree (as from scratch up to PhysX's contact cache: each phase's random streams are seeded by its depths).
case $name in G) from=0.006 ;; G2) from=0.002 ;; GF) from=0.006; extra="--side-depth 8 --push-children 30" ;;
  GT) from=0.006; extra="--side-depth 8 --push-children 30 --turn-depth 24 --turn-children 16" ;;
  *) echo "NAME is G, G2, GF or GT" >&2; exit 2 ;; esac
out=${OUT:-outputs/usb22}/$name
$BIN record-expert --task USBInsertion-v1 --seed 1000 --episodes 1 --out $out/expert --descent-step 0.001 --descend-from $from
$BIN sample --expert $out/expert/expert.h5 --out $out/tree.h5 --num-children 500 --expert-step-scale 4 \
  --outward-depth 10 --face-depth 8 --goal-presses 500 $extra
$BIN train-reward --dataset $out/tree.h5 --out $out/reward --preset quick --iterations 20000 --threads 1
$BIN examine --task USBInsertion-v1 --checkpoint $out/reward/drem.pt --out $out/examination --episodes 20
for seed in ${SEEDS:-0}; do
  $BIN train-policy --task USBInsertion-v1 --reward drem --seed $seed --steps 40000 --preset state --no-bf16 \
    --no-overlap-env --eval-episodes 10 --threads 1 --reward-checkpoint $out/reward/drem.pt \
    --out ${OUT:-outputs/usb22}/sac/$name/seed$seed
done
