"""The Push-T demonstrations through LeRobot's format and back, on the real data (issue 27's data checks).

    .venv/bin/python scripts/lerobot_roundtrip.py --work /tmp/rt --out results/lerobot-interop/roundtrip.json

1. export the zarr as a LeRobot v3.0 dataset (PNG frames, lossless) and import it again: every array and the
   episode bounds compared exactly;
2. the same with AV1 video (lossy, as the Hub's lerobot/pusht): how far the frames move;
3. a bcbench policy (CNN-MLP, fp32, batch 64, 50 optimiser steps, seed 0) trained from the zarr and from the
   imported copy: its first 50 logged losses side by side.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bcbench.data import load_replay_buffer, resolve_dataset
from bcbench.data.lerobot_format import export_lerobot
from bcbench.data.lerobot_import import import_lerobot
from bcbench.data.replay_buffer import write_replay_buffer
from bcbench.utils.io import atomic_dir, write_json
from bcbench.utils.system import provenance

KEYS = ("state", "action", "keypoint", "n_contacts", "images", "episode_ends")


def _size_mb(path: Path) -> float:
    return round(sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) / 1e6, 1)


def _losses(data: Path, run: Path, steps: int) -> list[float]:
    subprocess.run([sys.executable, "-m", "bcbench.cli", "train", "--policy", "cnn_mlp", "--preset", "quick",
                    "--data", str(data), "--out", str(run), "--seed", "0", "--quiet",
                    "--set", f"optim.max_steps={steps}", "--set", "optim.batch_size=64",
                    "--set", "optim.precision=fp32", "--set", "optim.log_every=1"], check=True)
    rows = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    return [r["train_loss"] for r in rows if "train_loss" in r][:steps]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", required=True, help="scratch folder (the datasets and runs go here)")
    ap.add_argument("--out", required=True, help="the JSON result file")
    ap.add_argument("--steps", type=int, default=50)
    args = ap.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    src = resolve_dataset(None)
    buf = load_replay_buffer(src)
    out: dict = {"type": "lerobot-roundtrip", "dataset": str(src), "episodes": buf.n_episodes, "frames": buf.n_steps}
    for video in (False, True):
        name = "video" if video else "png"
        t = time.perf_counter()
        export_lerobot(buf, work / f"lerobot-{name}", video=video, force=True)
        t_export = time.perf_counter() - t
        t = time.perf_counter()
        back = import_lerobot(work / f"lerobot-{name}")
        t_import = time.perf_counter() - t
        rec = {"export_s": round(t_export, 1), "import_s": round(t_import, 1),
               "size_mb": _size_mb(work / f"lerobot-{name}"),
               "identical": {k: bool(np.array_equal(getattr(buf, k), getattr(back, k))) for k in KEYS}}
        if video:
            diff = np.abs(back.images.astype(np.int16) - buf.images.astype(np.int16))
            mse = float((diff.astype(np.float64) ** 2).mean())
            rec["frames"] = {"mean_abs_error": float(diff.mean()), "max_abs_error": int(diff.max()),
                             "psnr_db": float(10 * np.log10(255**2 / mse))}
        else:
            with atomic_dir(work / "imported.zarr", force=True) as staged:
                write_replay_buffer(staged, back)
        out[name] = rec
        print(name, json.dumps(rec))
    a = _losses(src, work / "run-zarr", args.steps)
    b = _losses(work / "imported.zarr", work / "run-imported", args.steps)
    out["training"] = {"policy": "cnn_mlp", "preset": "quick", "batch_size": 64, "precision": "fp32", "seed": 0,
                       "steps": args.steps, "losses_from_zarr": a, "losses_from_imported": b,
                       "max_abs_difference": float(np.max(np.abs(np.array(a) - np.array(b)))),
                       "identical": a == b}
    print("training", out["training"]["max_abs_difference"], out["training"]["identical"])
    write_json(args.out, {**out, **provenance("cpu")})


if __name__ == "__main__":
    main()
