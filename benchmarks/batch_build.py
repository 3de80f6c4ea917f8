"""How long does building one training batch take, next to a model step?

    .venv/bin/python benchmarks/batch_build.py [--batch 64] [--iters 200]

Loads the real Push-T data (uint8 images in memory), builds the 90/10 split and the sequence dataset,
then times `get_batch` for random windows (numpy gather + normalise + uint8->float) and the conversion
to torch tensors. Prints median and p99 in milliseconds.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from bcbench.data import load_replay_buffer, make_datasets, resolve_dataset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--data", default=None)
    args = ap.parse_args()

    t0 = time.perf_counter()
    buf = load_replay_buffer(resolve_dataset(args.data))
    t_load = time.perf_counter() - t0
    train, val, _ = make_datasets(buf)
    rng = np.random.default_rng(0)
    for _ in range(10):  # warm-up
        train.get_batch(rng.integers(0, len(train), args.batch))
    times = []
    for _ in range(args.iters):
        ids = rng.integers(0, len(train), args.batch)
        t = time.perf_counter()
        batch = train.get_batch(ids)
        {k: torch.from_numpy(v) for k, v in batch.items()}
        times.append(time.perf_counter() - t)
    ms = np.array(times) * 1e3
    print(f"dataset load (uint8 images): {t_load:.1f} s; train windows {len(train)}, val windows {len(val)}")
    print(f"batch of {args.batch}: median {np.median(ms):.2f} ms, p99 {np.percentile(ms, 99):.2f} ms, "
          f"min {ms.min():.2f} ms over {args.iters} batches (torch threads {torch.get_num_threads()})")


if __name__ == "__main__":
    main()
