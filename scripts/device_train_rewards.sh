#!/usr/bin/env bash
# Trains the four shipped reward checkpoints (DREM and image-only, each task) on a GPU machine
# that has torch and h5py but no ManiSkill, from 64 px copies of the trees (scripts/slim_tree.py),
# all four at once on the one GPU. The same training as scripts/train_default_rewards.sh
# (--preset quick --iterations 20000: 64 px, 16 + 16 pairs a batch, Adam 2e-4), on CUDA.
#   bash scripts/device_train_rewards.sh TREES_DIR OUT_DIR [ITERS]
# TREES_DIR holds <task>.h5 or <task>.h5.xz (slim trees; `slim_tree.py --no-compression` then
# `xz` packs them about 40 % tighter than gzip inside HDF5, for a 64 MiB transfer); OUT_DIR gets
# <task>_reward.tgz and <task>_reward_image.tgz (drem.pt, config.json, tb/) and one log per run.
# Each run stops itself after LIMIT seconds (default 480) so that a time-limited machine still
# returns something: then the archive holds train_state.pt instead, to resume from (unpacked
# into WORK/<task>/reward*, same paths).
set -uo pipefail
trees=${1:?TREES_DIR}; out=${2:?OUT_DIR}; iters=${3:-20000}
work=${WORK:-/tmp/drem_rewards}; limit=${LIMIT:-480}
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
mkdir -p "$work" "$out"
export PYTHONUNBUFFERED=1 TQDM_MININTERVAL=10
for packed in "$trees"/*.h5.xz; do
  [ -e "$packed" ] || continue
  python3 -c "import lzma, shutil, sys; shutil.copyfileobj(lzma.open(sys.argv[1]), open(sys.argv[2], 'wb'), 1 << 24)" \
    "$packed" "$work/$(basename "$packed" .xz)"
done
for tree in "$trees"/*.h5 "$work"/*.h5; do
  [ -e "$tree" ] || continue
  task=$(basename "$tree" .h5)
  timeout "$limit" python3 "$here/train_reward_standalone.py" --dataset "$tree" --out "$work/$task/reward" \
    --iterations "$iters" --device "${DEVICE:-cuda}" > "$out/$task.log" 2>&1 &
  timeout "$limit" python3 "$here/train_reward_standalone.py" --dataset "$tree" --out "$work/$task/reward_image" \
    --iterations "$iters" --device "${DEVICE:-cuda}" --modalities fixed wrist > "$out/${task}_image.log" 2>&1 &
done
wait
# One archive per run (a device machine returns files of at most 16 MB): the checkpoint, or the
# train state to resume from where a run was cut off.
for run in "$work"/*/reward "$work"/*/reward_image; do
  [ -d "$run" ] || continue
  name=$(basename "$(dirname "$run")")_$(basename "$run")
  if [ -f "$run/drem.pt" ]; then files=(drem.pt config.json tb); else files=(train_state.pt config.json tb); fi
  (cd "$run" && tar czf "$out/$name.tgz" "${files[@]}")
done
ls -la "$out"
