"""One training with every thread, or one training per core side by side: which trains more samples/s here?

    .venv/bin/python benchmarks/train_threads.py [--policy diffusion] [--config cpu] [--batch 64] [--seconds 40]
        [--out results/train-throughput/threads]

A study's trainings are independent, so on a 2-core machine it can run one at a time with 2 torch threads or two
at a time with 1 thread each (`resources = { train = { cpus = 1 } }` under `--ray`). Small-batch training scales
poorly across threads, so the second can train more samples per second in all. Measured here, one after another:
(1) one process, all cores' threads; (2) one process, 1 thread; (3) one 1-thread process per core, side by side,
started together (each times its own window once its data is loaded); (4) (1) again, to see the machine's drift.
Each process: fp32 training steps of the policy's preset at the given batch (the code of `bcbench train` via
train_throughput.step_fn, real training windows), 3 warm-up steps, then steps for --seconds. Stop anything else
running first. Writes threads.json (with CPU model, flags and commit) and prints the table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from bcbench.utils.io import atomic_path, write_json
from bcbench.utils.system import CpuContention, provenance


def worker(policy: str, config: str, batch: int, threads: int, seconds: float) -> None:
    import torch

    sys.path.insert(0, str(Path(__file__).parent))
    from train_throughput import load_train_windows, step_fn

    from bcbench.policies import make_config
    from bcbench.training.parts import keep_freed_memory

    torch.set_num_threads(threads)
    keep_freed_memory()
    step = step_fn(policy, make_config(policy, config), "fp32", batch, True, load_train_windows())
    for _ in range(3):
        step()
    t0, n = time.perf_counter(), 0
    while time.perf_counter() - t0 < seconds:
        step()
        n += 1
    print(json.dumps({"threads": threads, "steps": n, "samples_per_s": n * batch / (time.perf_counter() - t0)}))


def run(args: argparse.Namespace, threads: int, copies: int) -> list[dict]:
    cmd = [sys.executable, __file__, "--worker", "--policy", args.policy, "--config", args.config, "--batch",
           str(args.batch), "--seconds", str(args.seconds), "--threads", str(threads)]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True) for _ in range(copies)]
    return [json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--policy", default="diffusion")
    ap.add_argument("--config", default="cpu")
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--threads", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", default="results/train-throughput/threads")
    args = ap.parse_args()
    if args.worker:
        worker(args.policy, args.config, args.batch, args.threads, args.seconds)
        return
    cores = os.cpu_count() or 1
    rows = {}
    with CpuContention() as busy:
        for name, threads, copies in ((f"one process, {cores} threads", cores, 1), ("one process, 1 thread", 1, 1),
                                      (f"{cores} processes side by side, 1 thread each", 1, cores),
                                      (f"one process, {cores} threads, again", cores, 1)):
            res = run(args, threads, copies)
            rows[name] = {"processes": res, "total_samples_per_s": sum(r["samples_per_s"] for r in res)}
            each = ", ".join(f"{r['samples_per_s']:.1f}" for r in res)
            print(f"{name}: {rows[name]['total_samples_per_s']:.1f} samples/s ({each})", flush=True)
    busy.warn("the training throughput")
    alone = [v["total_samples_per_s"] for k, v in rows.items() if k.startswith(f"one process, {cores}")]
    side = rows[f"{cores} processes side by side, 1 thread each"]["total_samples_per_s"]
    record = {"type": "train-threads", "policy": args.policy, "config": args.config, "batch": args.batch,
              "precision": "fp32", "seconds": args.seconds, "rows": rows,
              "side_by_side_over_all_threads": side / (sum(alone) / len(alone)),
              "cpu_contention_of_others": busy.result, **provenance()}
    out = Path(args.out)
    write_json(out / "threads.json", record)
    with atomic_path(out / "threads.md") as tmp:
        tmp.write_text("\n".join(f"- {k}: {v['total_samples_per_s']:.1f} samples/s" for k, v in rows.items())
                       + f"\n- side by side / all threads in one (mean of the two): "
                       f"{record['side_by_side_over_all_threads']:.2f}x\n")
    print(f"side by side / one with all threads: {record['side_by_side_over_all_threads']:.2f}x; wrote {out}")


if __name__ == "__main__":
    main()
