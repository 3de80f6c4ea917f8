#!/usr/bin/env bash
# bcbench's CUDA paths on a lent GPU, in one short run (a machine is lent to few sessions, for minutes).
#
#   1. train: every learned policy, `quick` preset, STEPS optimiser steps on the GPU at the default precision
#      (auto: bf16 autocast on a bf16-capable GPU), then `bcbench eval --device cuda` on a few short episodes;
#   2. resume: a diffusion run "crashed" after its half-way checkpoint and resumed on the GPU against an
#      uninterrupted run, and a second uninterrupted run against the first (the GPU's own run-to-run spread,
#      where its kernels sum in varying order; on the H200 of results/gpu-h200 all three were bit-identical);
#   3. latency: `bcbench latency --device cuda`, reference mode, at the study's sizes (`paper`) beside its A100
#      per-step times, and the CPU study's published presets (`cpu`) in reference and fast mode.
# Everything small comes back as $OUT/gpu-check.tar.gz, the log as $OUT/log.txt.
#
# On the device machine: wheels of the packages its image lacks in .whl/ and a 40-episode subset of the Push-T data
# in .gpu/ (both ignored by git, carried by the device tool); results/ and models/ taken out of the index for the
# call (the tree that travels must stay under 64 MiB; `git reset -- results models` after). The commit is read HERE
# and written into the command, since the copy's .git there can be a stale snapshot:
#   BCBENCH_COMMIT=<git rev-parse HEAD, here> DATA=.gpu/pusht40.zarr scripts/gpu_check.sh
# A dry run here, on the CPU: DEVICE=cpu STEPS=4 PAPER_STEPS=1 QUICK_TIMING=--quick PYTHON=.venv/bin/python OUT=/tmp/g
#   BCBENCH_COMMIT=test DATA=.gpu/pusht40.zarr scripts/gpu_check.sh
set -u
DEV=${DEVICE:-cuda}
STEPS=${STEPS:-120}
OUT=${OUT:?set OUT, the folder that comes back}
DATA=${DATA:?set DATA, a Push-T zarr}
: "${BCBENCH_COMMIT:?set BCBENCH_COMMIT to the commit copied there (git rev-parse HEAD where you launch it), since a copied .git can be stale}"
PY=${PYTHON:-python3}
WORK=${WORK:-/tmp/gpu-check}
QUICK=${QUICK_TIMING:-}           # --quick: fewer timed calls (dry runs)
PAPER_STEPS=${PAPER_STEPS:-10 100}  # denoising steps timed at the study's sizes (the A100 table has 10 and 100)
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}"
BC="$PY -m bcbench.cli"
rm -rf "$WORK"; mkdir -p "$WORK/runs" "$WORK/latency" "$OUT"
exec > >(tee -a "$OUT/log.txt") 2>&1

step() {  # step NAME COMMAND...: run, time, and record the exit status; a failure does not stop later steps
  local name=$1; shift
  local t0=$SECONDS
  echo "=== $name: $*"
  "$@"; local rc=$?
  printf '%s\t%s\t%s\n' "$name" "$rc" "$((SECONDS - t0))" >> "$WORK/steps.tsv"
  echo "=== $name: exit $rc"
}

echo "commit ${BCBENCH_COMMIT:-unknown}, device $DEV, $STEPS steps, $(date -u +%FT%TZ)"
[ "$DEV" = cuda ] && nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.sm --format=csv
$PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda, 'available', torch.cuda.is_available())"

# 1. every learned policy trains on the device, then its checkpoint is evaluated there
for p in cnn_mlp resnet50 bct bet diffusion flow; do
  step "train-$p" $BC train --policy "$p" --preset quick --device "$DEV" --data "$DATA" --quiet \
    --set optim.max_steps="$STEPS" --set optim.checkpoint_every="$STEPS" --set optim.log_every=10 \
    --out "$WORK/runs/$p"
done
for p in diffusion flow bct; do
  step "eval-$p" $BC eval --checkpoint "$WORK/runs/$p" --device "$DEV" --episodes 2 --max-steps 48 \
    --out "$WORK/runs/$p/eval-gpu"
done

# 2. resume after a crash at the half-way checkpoint, against two uninterrupted runs
HALF=$((STEPS / 2))
for r in a b c; do
  step "resume-$r" $BC train --policy diffusion --preset quick --device "$DEV" --data "$DATA" --quiet \
    --set optim.max_steps="$STEPS" --set optim.checkpoint_every="$HALF" --set optim.log_every=5 \
    --out "$WORK/runs/resume-$r"
done
$PY - "$WORK/runs/resume-c" "$HALF" <<'EOF'
import json, shutil, sys
from pathlib import Path
run, half = Path(sys.argv[1]), int(sys.argv[2])
ckpts = run / "checkpoints"
last = json.loads((ckpts / "latest.json").read_text())
shutil.rmtree(ckpts / last["dir"])  # the crash: the final checkpoint never got written
(ckpts / "latest.json").write_text(json.dumps({"step": half, "dir": f"step_{half:07d}"}))
(run / "train_summary.json").unlink()
print(f"resume-c: final checkpoint {last['dir']} removed; resuming from step {half}")
EOF
step "resume-c-resumed" $BC train --resume "$WORK/runs/resume-c" --device "$DEV" --data "$DATA" --quiet
$PY - "$WORK/runs" "$HALF" <<'EOF' | tee "$WORK/resume.json"
import json, sys
from pathlib import Path
from safetensors.torch import load_file
from bcbench.policies.checkpoint import latest_checkpoint
from bcbench.utils.io import read_jsonl
runs, half = Path(sys.argv[1]), int(sys.argv[2])
def losses(name):
    rows = read_jsonl(runs / name / "metrics.jsonl")
    return {r["step"]: r["train_loss"] for r in rows if "train_loss" in r and r["step"] > half}
def weights(name):
    return load_file(str(latest_checkpoint(runs / name) / "model.safetensors"))
def gap(x, y):  # largest relative difference of the logged losses after the resume point, and of the weights
    la, lb = losses(x), losses(y)
    common = sorted(set(la) & set(lb))
    wa, wb = weights(x), weights(y)
    wgap = max(float((wa[k].float() - wb[k].float()).abs().max()) for k in wa)
    rel = max((abs(la[s] - lb[s]) / abs(la[s]) for s in common), default=None)
    return {"steps_compared": len(common), "max_rel_loss_gap": rel, "max_abs_weight_gap": wgap}
print(json.dumps({"after_step": half, "resumed_vs_uninterrupted": gap("resume-a", "resume-c"),
                  "uninterrupted_vs_uninterrupted": gap("resume-a", "resume-b")}, indent=1))
EOF

# 3. latency on the device: the study's sizes in reference mode, the CPU study's presets as users get them
step "latency-paper" $BC latency --device "$DEV" --preset paper --mode reference $QUICK \
  --policy cnn_mlp --policy resnet50 --policy bct --policy diffusion \
  --sampler ddpm --sampler ddim $(printf -- "--steps %s " $PAPER_STEPS) --out "$WORK/latency/paper"
step "latency-paper-flow" $BC latency --device "$DEV" --preset paper --mode reference $QUICK \
  --policy flow --sampler euler --steps 2 --steps 10 --out "$WORK/latency/paper-flow"
step "latency-cpu" $BC latency --device "$DEV" --preset cpu --mode reference --mode fast $QUICK \
  --policy diffusion --sampler ddim --steps 10 --out "$WORK/latency/cpu-dp"
step "latency-cpu-flow" $BC latency --device "$DEV" --preset cpu --mode reference --mode fast $QUICK \
  --policy flow --sampler euler --steps 2 --steps 10 --out "$WORK/latency/cpu-flow"

# what comes back: run records (no weights), evaluations, latency records, the step table
cat "$WORK/steps.tsv"
(cd "$WORK" && find . -name "*.json" -o -name "*.jsonl" -o -name "*.md" -o -name "*.png" -o -name "*.tsv" \
  | grep -v "/checkpoints/" | tar czf "$OUT/gpu-check.tar.gz" -T -)
ls -la "$OUT"
