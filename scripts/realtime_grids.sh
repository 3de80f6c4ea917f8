#!/usr/bin/env bash
# Issue 76's three-seed sweeps: for Diffusion Policy (DDIM-10) and flow matching (Euler-10), training seeds 0-2, every
# trained model this machine holds gets its correction head (A2C2's recipe, chosen on validation:
# results/correction-head-dp-s0/README.md, "The head the three-seed sweep runs") and its sweep (scripts/realtime_grid.sh:
# naive at the default horizon, naive and RTC at matched horizons, the delay-trained model's prefix, the head), 100
# test episodes a setting. Seed 0's plain models are the published ones (models/); seeds 1-2 come from
# studies/realtime-seeds.toml, the delay-trained ones from studies/realtime-delay-train.toml (their run folders under
# $BCBENCH_HOME). A model not trained yet is skipped and said so; rerun when it is: every finished head and setting is
# kept (resumable). One computation at a time: run it in the background, nothing else timing on the machine.
#   scripts/realtime_grids.sh [OUT]     (default $BCBENCH_HOME/grids; then export each OUT/POLICY-sSEED)
set -euo pipefail
cd "$(dirname "$0")/.."
H="${BCBENCH_HOME:-$HOME/.cache/bcbench}"
OUT="${1:-$H/grids}"
PY=.venv/bin/python
finished() { [ -f "$1/train_summary.json" ] && grep -q '"stopped": "finished"' "$1/train_summary.json"; }
run_of() {  # $1 study, $2 policy, $3 seed: its finished run folder with its weights here, or nothing
  local d
  for d in "$H/$1/runs/$2-cpu-s$3-"*; do
    finished "$d" || continue
    # a run restored from a committed export (a new machine: bcbench.study.restore) has its records, not its weights
    if [ -z "$(ls -A "$d/checkpoints" 2>/dev/null)" ]; then
      echo "$1 $2 seed $3: $d was trained on another machine and its weights are not here; its sweep needs the" \
           "model its evaluations read: move the folder aside and resume the study to train it again" >&2
      continue
    fi
    echo "$d"; return
  done
}
for spec in "diffusion ddim dp" "flow euler flow"; do
  set -- $spec
  policy=$1 sampler=$2 short=$3
  for seed in 0 1 2; do
    if [ "$seed" = 0 ]; then plain="models/$policy-cpu"; else plain="$(run_of realtime-seeds "$policy" "$seed")"; fi
    if [ -z "$plain" ] || [ ! -f "$plain/run.json" ]; then echo "skip $short-s$seed: the plain model is not trained yet"; continue; fi
    dt="$(run_of realtime-delay-train "$policy" "$seed")"
    [ -n "$dt" ] || echo "$short-s$seed: no delay-trained model yet (its prefix settings wait)"
    head="$OUT/heads/$short-s$seed"
    if ! finished "$head"; then
      if [ -f "$head/run.json" ]; then res=(--resume "$head"); else res=(--out "$head"); fi
      echo "$(date -u +%FT%T) head for $short-s$seed on $plain"
      nice -n 10 $PY -m bcbench.cli train --policy correction --preset cpu --set "base=$plain" \
        --set "base_sampler=$sampler" --set base_steps=10 --set optim.precision=fp32 --seed 0 --threads 2 --quiet \
        "${res[@]}"
    fi
    echo "$(date -u +%FT%T) sweep $short-s$seed"
    scripts/realtime_grid.sh "$sampler" 10 "$plain" "$OUT/$short-s$seed" "${dt:--}" "$head"
  done
done
echo "$(date -u +%FT%T) done: $OUT"
