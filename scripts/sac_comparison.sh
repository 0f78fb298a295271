#!/usr/bin/env bash
# The SAC comparison of docs/results.md (the paper's Fig. 5 at this machine's scale): every
# reward x seed on a task, two runs at a time (one torch thread each), then the curves and the
# table. Each run resumes if interrupted; rerun to continue.
#   bash scripts/sac_comparison.sh [TASK] [STEPS] [SEEDS] [REWARDS...]
#   defaults: PegInHole-v1 1500 "0 1 2" sparse engineered vice drem-image drem
#   env: OUT (outputs/rl), PARALLEL (2), PRESET (light), and EVAL_EVERY, EVAL_EPISODES,
#   LEARNING_STARTS (default: the preset's own), EXTRA (more train-policy options)
#   the state-preset comparison of docs/results.md (its runs train in float32 with the env in the
#   training process, hence EXTRA), for each of PegInHole-v1 and USBInsertion-v1:
#     EXTRA="--no-bf16 --no-overlap-env" PRESET=state bash scripts/sac_comparison.sh PegInHole-v1 50000
#   the light-preset runs: bash scripts/sac_comparison.sh PegInHole-v1 40000 "0 1 2" sparse engineered drem
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
TASK=${1:-PegInHole-v1}
STEPS=${2:-1500}
SEEDS=${3:-"0 1 2"}
shift $(( $# < 3 ? $# : 3 ))
REWARDS=("$@")
[ ${#REWARDS[@]} -gt 0 ] || REWARDS=(sparse engineered vice drem-image drem)
BIN=.venv/bin/drem-maniskill
OUT=${OUT:-outputs/rl}
PRESET=${PRESET:-light}
export OMP_WAIT_POLICY=PASSIVE
OPTS="--preset $PRESET${EVAL_EVERY:+ --eval-every $EVAL_EVERY}${EVAL_EPISODES:+ --eval-episodes $EVAL_EPISODES}"
OPTS="$OPTS${LEARNING_STARTS:+ --learning-starts $LEARNING_STARTS}${EXTRA:+ $EXTRA}"
jobs=()
for seed in $SEEDS; do for reward in "${REWARDS[@]}"; do jobs+=("$reward $seed"); done; done
mkdir -p "$OUT/logs"
printf '%s\n' "${jobs[@]}" | xargs -P "${PARALLEL:-2}" -L 1 bash -c \
  "$BIN train-policy --task $TASK --reward \$0 --seed \$1 --steps $STEPS $OPTS --threads 1 \
   --out $OUT/$TASK/\$0/seed\$1 > $OUT/logs/$TASK-\$0-\$1.log 2>&1 && echo done \$0 \$1"
$BIN compare "$OUT/$TASK"/*/seed* --out "$OUT/comparison-$TASK"
