#!/usr/bin/env bash
# Keep a copy of one checkpoint of a study's run before the study prunes it (a run keeps its last three), e.g.
# BID's weak policy, an early checkpoint of the same recipe:
#   scripts/keep_checkpoint.sh ~/.cache/bcbench/cpu-confirm-dpflow/runs/diffusion-cpu-s1-* 4000 \
#       ~/.cache/bcbench/weak-diffusion-confirm-s1-step4000 &
# Waits until the run writes step STEP, then copies run.json, normalizer.json and that checkpoint (nothing else)
# into DEST, a run folder `--checkpoint` and `--bid-weak` take. The glob may name a run that does not exist yet.
set -euo pipefail
[ $# -eq 3 ] || { echo "usage: $0 RUN_GLOB STEP DEST" >&2; exit 2; }
GLOB=$1 STEP=$2 DEST=$3
CK=$(printf 'step_%07d' "$STEP")
[ -e "$DEST" ] && { echo "error: $DEST exists" >&2; exit 2; }
while true; do
  for run in $GLOB; do
    latest=$(grep -o '"step": [0-9]*' "$run/checkpoints/latest.json" 2>/dev/null | grep -o '[0-9]*$' || echo -1)
    # latest.json names a checkpoint only once it is complete (checkpoint.py writes it last)
    if [ -d "$run/checkpoints/$CK" ] && [ "$latest" -ge "$STEP" ]; then
      mkdir -p "$DEST.tmp/checkpoints"
      cp "$run/run.json" "$run/normalizer.json" "$DEST.tmp/"
      cp -r "$run/checkpoints/$CK" "$DEST.tmp/checkpoints/"
      printf '{\n  "step": %d,\n  "dir": "%s"\n}\n' "$STEP" "$CK" > "$DEST.tmp/checkpoints/latest.json"
      mv "$DEST.tmp" "$DEST"
      echo "kept $run step $STEP in $DEST"
      exit 0
    fi
  done
  sleep 10
done
