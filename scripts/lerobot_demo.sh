#!/usr/bin/env bash
# A LeRobot Diffusion Policy trained briefly on bcbench's exported demonstrations, scored and timed by bcbench
# beside bcbench's own quick Diffusion Policy, on the same validation seeds (200000-200049; nothing is chosen
# from these numbers). Writes results/lerobot-interop/ (eval-*/eval.json per episode, latency-*/latency.json).
#   scripts/lerobot_demo.sh [WORK_DIR]        (default /tmp/bcbench-lerobot-demo; about 1.5 hours on 2 cores)
# Stop any background study first: the timings mean nothing beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
make -s install lerobot-env
WORK="${1:-/tmp/bcbench-lerobot-demo}"
OUT=results/lerobot-interop
BC=.venv/bin/bcbench
mkdir -p "$WORK" "$OUT"
[ -d "$WORK/pusht-lerobot" ] || $BC data export --to lerobot "$WORK/pusht-lerobot"

# LeRobot's DP, its Push-T windows (2 observations, 16 actions, 8 executed, 84x84 crops), a 64/128/256 U-Net
# (bcbench's quick width) with LeRobot's full ResNet-18, DDIM-10 at inference; 300 steps of batch 32 (CPU).
if [ ! -d "$WORK/lerobot-dp/checkpoints/last/pretrained_model" ]; then
  /usr/bin/time -f "%e" -o "$WORK/lerobot-dp.seconds" .lerobot-venv/bin/lerobot-train \
    --dataset.repo_id=local/pusht --dataset.root="$WORK/pusht-lerobot" --policy.type=diffusion \
    --policy.device=cpu --policy.push_to_hub=false --policy.horizon=16 --policy.n_action_steps=8 \
    "--policy.crop_shape=[84,84]" "--policy.down_dims=[64,128,256]" --policy.pretrained_backbone_weights=null \
    --policy.scheduler_warmup_steps=30 --policy.noise_scheduler_type=DDIM --policy.num_inference_steps=10 \
    --steps=300 --batch_size=32 --env_eval_freq=0 --save_freq=300 --log_freq=25 --num_workers=1 --seed=0 \
    --output_dir="$WORK/lerobot-dp" --wandb.enable=false
fi
LR="$WORK/lerobot-dp/checkpoints/last/pretrained_model"

# bcbench's quick DP on the imported copy of the same export (the round trip is exact: roundtrip.json).
[ -d "$WORK/pusht.zarr" ] || $BC data import --from lerobot "$WORK/pusht-lerobot" --out "$WORK/pusht.zarr"
[ -f "$WORK/bcbench-dp/train_summary.json" ] || \
  $BC train --policy diffusion --preset quick --precision fp32 --data "$WORK/pusht.zarr" --out "$WORK/bcbench-dp" --quiet
cp "$WORK/bcbench-dp/train_summary.json" "$OUT/bcbench-dp-train_summary.json"
cp "$WORK/lerobot-dp/checkpoints/last/pretrained_model/train_config.json" "$OUT/lerobot-dp-train_config.json"

EVAL=(--episodes 50 --seed-start 200000 --quiet)
$BC eval --policy "lerobot:$LR" "${EVAL[@]}" --out "$OUT/eval-lerobot-dp-ddim10"
$BC eval --checkpoint "$WORK/bcbench-dp" --sampler ddim --steps 10 "${EVAL[@]}" --out "$OUT/eval-bcbench-dp-ddim10"
# one call at batch 1, 2 threads, in interleaved rounds (separate blocks drift by tens of percent on a VM):
# LeRobot's DP beside bcbench's quick DP in torch (as LeRobot runs) and in OpenVINO fp32 (what auto picks here)
.venv/bin/python benchmarks/lerobot_paired_latency.py "$LR" --out "$OUT/latency-paired"
# LeRobot's ACT at Push-T's chunk (16, 8 executed), random weights: a call's time does not depend on them
.lerobot-venv/bin/python tests/sidecar/make_random_lerobot.py act "$WORK/act-random"
$BC latency --policy "lerobot:$WORK/act-random" --threads 2 --out "$OUT/latency-lerobot-act-random"
