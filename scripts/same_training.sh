#!/usr/bin/env bash
# Does the training code of two commits give the same model? Trains one configuration for a few optimiser steps at
# each commit (from clean clones, with the work tree's .venv) on this machine and compares the weights bit for bit.
# Used where a study carries over a run trained at another commit (a mixing-reason.txt says so), e.g. stage 4's BeT:
#   scripts/same_training.sh 28df21a 8caac26 bet cpu 40 --set optim.precision=fp32 --set optim.batch_size=64
# Exit 0 when every tensor is identical, 1 when any differs. Do not run it beside a timing.
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 5 ] || { echo "usage: $0 COMMIT_A COMMIT_B POLICY PRESET STEPS [--set KEY=VALUE ...]" >&2; exit 2; }
A=$1 B=$2 POLICY=$3 PRESET=$4 STEPS=$5; shift 5
export BCBENCH_DATA="${BCBENCH_DATA:-$PWD/../shared/data/pusht/pusht_cchi_v7_replay.zarr}"
TMP=$(mktemp -d); trap 'rm -rf "$TMP"' EXIT
for C in "$A" "$B"; do
  git rev-parse --verify --quiet "$C^{commit}" >/dev/null || { echo "error: no commit $C" >&2; exit 2; }
  git clone --quiet --no-checkout "$PWD" "$TMP/src-$C" && git -C "$TMP/src-$C" checkout --quiet "$C"
  (cd "$TMP/src-$C" && PYTHONPATH="$TMP/src-$C/src" "$OLDPWD/.venv/bin/python" -m bcbench.cli train --policy "$POLICY" \
     --config "$PRESET" "$@" --set "optim.max_steps=$STEPS" --quiet --out "$TMP/run-$C" >/dev/null)
done
.venv/bin/python - "$TMP/run-$A" "$TMP/run-$B" "$A" "$B" <<'PY'
import sys
from pathlib import Path

import torch
from safetensors.torch import load_file

runs = [sorted(Path(r).glob("checkpoints/step_*/model.safetensors"))[-1] for r in sys.argv[1:3]]
a, b = (load_file(str(f)) for f in runs)
if a.keys() != b.keys():
    sys.exit(f"different parameters: {sorted(a.keys() ^ b.keys())[:5]}")
diff = max((a[k].double() - b[k].double()).abs().max().item() for k in a)
same = all(torch.equal(a[k], b[k]) for k in a)
print(f"{sys.argv[3]} vs {sys.argv[4]}: {runs[0].parent.name}, {len(a)} tensors, largest difference {diff:g}: "
      + ("identical" if same else "DIFFERENT"))
sys.exit(0 if same else 1)
PY
