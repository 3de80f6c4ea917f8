#!/usr/bin/env bash
# The CPU study's real-time scores with a deployment backend (issue 14: each policy's real-time score on this
# CPU with its fastest backend). For every policy the study swept (its own sweeps run in torch), this times
# the same checkpoint and setting in OpenVINO (fp32 by default: exact, the fastest exact backend here) and
# scores it at that measured latency, blocking and async, beside sync. Each sweep lands inside the study's
# folder (RUN/realtime-openvino-PRECISION/), so `bcbench report STUDY` shows it beside the torch sweeps.
#   scripts/cpu_realtime_backend.sh [STUDY_DIR] [fp32|bf16|int8]    (default ~/.cache/bcbench/cpu, fp32)
# Run it after the study with nothing else on the machine: every sweep times its policy first.
set -euo pipefail
cd "$(dirname "$0")/.."
STUDY="${1:-$HOME/.cache/bcbench/cpu}"
PRECISION="${2:-fp32}"
[ -f "$STUDY/index.jsonl" ] || { echo "error: $STUDY is not a study folder (no index.jsonl)" >&2; exit 2; }
# run folder, label, sampler, steps of each of the study's own sweeps (not of earlier runs of this script)
list_sweeps() {
  .venv/bin/python - "$STUDY" <<'PY'
import json, sys
from pathlib import Path
for f in sorted(Path(sys.argv[1]).glob("runs/*/realtime-*.json")):
    rec = json.loads(f.read_text())
    if rec.get("type") == "realtime" and rec["study"]["name"] != "bcbench realtime":
        v = rec["study"]["variant"]
        print("\t".join([str(f.parent), rec["study"]["label"], v.get("sampler") or "-", str(v.get("steps") or "-")]))
PY
}
while IFS=$'\t' read -r run label sampler steps; do
  [ -f "$run/run.json" ] || continue  # a baseline: nothing to deploy
  gen=()
  [ "$sampler" != "-" ] && gen=(--sampler "$sampler" --steps "$steps")  # the report appends e.g. DDIM10
  echo "== $label: OpenVINO $PRECISION"
  .venv/bin/bcbench realtime --checkpoint "$run" "${gen[@]}" --backend openvino --precision "$PRECISION" \
      --measured --delays 0 --out "$run/realtime-openvino-$PRECISION" --label "$label [OpenVINO $PRECISION]" --quiet
done < <(list_sweeps)
