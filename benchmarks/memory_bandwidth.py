"""What bounds Diffusion Policy's latency at batch 1 on this machine: a measured memory-bandwidth floor.

    .venv/bin/python benchmarks/memory_bandwidth.py [--threads 2]

At batch 1 every denoising step reads all U-Net weights once (the activations are tiny: 16 time steps).
This script measures (1) how fast torch streams a buffer the size of the U-Net's weights from memory
(a sum over 80 M fp32 values, median of 10), and (2) one U-Net call at paper size in eager fp32, and
prints the implied floor for K denoising steps and how close the U-Net gets to it.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from bcbench.evaluation.floor import wall_times
from bcbench.policies import make_policy


def median_time(fn, n: int = 10) -> float:
    return float(np.median(wall_times(fn, n)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    model = make_policy("diffusion", "paper").eval()
    n_unet = sum(p.numel() for p in model.unet.parameters())
    n_film = sum(b.cond_encoder[1].weight.numel() + b.cond_encoder[1].bias.numel()
                 for b in model.unet.residual_blocks())
    buf = torch.rand(n_unet)
    t_read = median_time(lambda: buf.sum())
    gbps = n_unet * 4 / t_read / 1e9
    x, t, cond = torch.randn(1, 16, 2), torch.tensor(10), torch.randn(1, 1028)
    with torch.inference_mode():
        t_unet = median_time(lambda: model.unet(x, t, cond))
    floor_full = n_unet * 4 / (gbps * 1e9)
    floor_conv = (n_unet - n_film) * 4 / (gbps * 1e9)
    print(f"threads {torch.get_num_threads()}; U-Net {n_unet:,} parameters ({n_unet * 4 / 1e6:.0f} MB fp32), "
          f"of which FiLM {n_film:,}")
    print(f"streaming read: {gbps:.1f} GB/s -> reading the U-Net once takes {1e3 * floor_full:.1f} ms "
          f"({1e3 * floor_conv:.1f} ms without the FiLM weights)")
    print(f"one eager U-Net call at batch 1: {1e3 * t_unet:.1f} ms = {t_unet / floor_full:.2f}x the read floor")
    for k in (1, 10, 100):
        print(f"  {k:>3} denoising steps: floor {1e3 * k * floor_conv:.0f} ms (FiLM hoisted), "
              f"eager {1e3 * k * t_unet:.0f} ms")


if __name__ == "__main__":
    main()
