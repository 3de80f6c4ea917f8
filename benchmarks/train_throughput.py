"""Training samples/s of every learned policy at its quick and paper size on this machine.

    .venv/bin/python benchmarks/train_throughput.py [--steps 3] [--threads 2] [--policy NAME ...]

One optimiser step = forward, loss, backward, Adam update on a batch of 64 random windows of the real
shapes (2 frames of 96x96, 16x2 chunk); the median over --steps steps after one warm-up step. Data loading
is not included (see batch_build.py: about 2.5 ms per batch of 64).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from bcbench.policies import learned_policies, make_policy


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--policy", action="append")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    g = torch.Generator().manual_seed(0)
    b = args.batch
    batch = {"image": torch.rand(b, 2, 3, 96, 96, generator=g), "agent_pos": torch.rand(b, 2, 2, generator=g) * 2 - 1,
             "action": torch.rand(b, 16, 2, generator=g) * 2 - 1}
    print(f"| policy | preset | parameters | samples/s (batch {b}, {torch.get_num_threads()} threads) |")
    print("|---|---|---|---|")
    for name in args.policy or learned_policies():
        for preset in ("quick", "paper"):
            torch.manual_seed(0)
            model = make_policy(name, preset).train()
            opt = torch.optim.Adam(model.parameters(), lr=1e-4)
            times = []
            for i in range(args.steps + 1):
                t = time.perf_counter()
                loss = model.compute_loss(batch)
                opt.zero_grad()
                loss.backward()
                opt.step()
                if i:
                    times.append(time.perf_counter() - t)
            print(f"| {name} | {preset} | {model.num_parameters():,} | {b / np.median(times):.1f} |", flush=True)


if __name__ == "__main__":
    main()
