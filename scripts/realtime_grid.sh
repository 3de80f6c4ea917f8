#!/usr/bin/env bash
# Issue 76's sweep for one trained model: every strategy against naive at d in {1, 2, 4, 6, 8} (sync as d = 0), 100 test
# episodes a setting, at matched execution horizons, so that each strategy's gain splits into the horizon's step and
# the method's (scripts/recovery.py --naive-at-horizon):
#   OUT/default/          naive at the default horizon (s = 8 - d)
#   OUT/matched/{naive,rtc}/   naive and RTC (J = I) at s = 8 (d <= 6) and s = 7 (d = 8, the most a 16-action chunk holds)
#   OUT/prefix/{naive,prefix}/ the delay-trained model (DT_RUN) at the same horizons, when given
#   OUT/correction/{naive,correction}/ the plain model with its correction head (HEAD_RUN), when given
# Resumable (--resume keeps every finished setting; sync is run once a folder). One sweep at a time, in the background at
# low priority, nothing else timing on the machine (no setting here is a timing: delays are simulated).
#   scripts/realtime_grid.sh SAMPLER STEPS MODEL OUT [DT_RUN|-] [HEAD_RUN|-]
#   e.g. scripts/realtime_grid.sh ddim 10 models/diffusion-cpu ~/.cache/bcbench/grid/dp-s0 RUNS/dp-delay-s0 RUNS/dp-head-s0
set -euo pipefail
[ $# -ge 4 ] || { echo "usage: $0 SAMPLER STEPS MODEL OUT [DT_RUN|-] [HEAD_RUN|-]" >&2; exit 2; }
SAMPLER=$1 STEPS=$2 MODEL=$3 OUT=$4 DT=${5:--} HEAD=${6:--}
cd "$(dirname "$0")/.."
for d in "$MODEL" ${DT#-} ${HEAD#-}; do [ -e "$d/run.json" ] || { echo "error: no run at $d" >&2; exit 2; }; done
RT=(nice -n 10 .venv/bin/bcbench realtime --sampler "$SAMPLER" --steps "$STEPS" --execution async --episodes 100
    --rtc-no-jacobian --resume --quiet)
matched() {  # $1 checkpoint, $2 folder, the rest: strategies and their options
  local ckpt=$1 where=$2; shift 2
  "${RT[@]}" --checkpoint "$ckpt" --delays 1 2 4 6 --execution-horizon 8 --out "$where" "$@"
  "${RT[@]}" --checkpoint "$ckpt" --delays 8 --execution-horizon 7 --out "$where" "$@"
}
"${RT[@]}" --checkpoint "$MODEL" --delays 1 2 4 6 8 --out "$OUT/default"
matched "$MODEL" "$OUT/matched" --strategy naive rtc
[ "$DT" = - ] || matched "$DT" "$OUT/prefix" --strategy naive prefix
[ "$HEAD" = - ] || matched "$MODEL" "$OUT/correction" --strategy naive correction --correction "$HEAD"
echo "done: $OUT"
