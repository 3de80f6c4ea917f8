"""What each execution strategy's request costs, timed in interleaved rounds (the measured latency's ratios
without the drift of timing one strategy's block after another's).

    .venv/bin/python benchmarks/strategy_cost.py RUN_DIR [--sampler ddim --steps 10] [--strategies naive rtc]
                [--rounds 20] [--calls 5] [--backend torch] [--threads 2] [--out results/strategies-dp-a]

`bcbench realtime --measured` times each strategy's requests in a block of its own, one sweep after the other:
on this project's VMs a block timed after another sweep's episodes (batch 100) ran 6-9 ms slower for the very same
request (`results/strategies-dp-a/README.md`), so a difference between two strategies' measured medians can be
the order they ran in. Here each strategy makes --calls requests in each of --rounds rounds, in turn, exactly as
the measured latency makes them (`Strategy.request` at batch 1, after a chunk the policy made, RTC's soft mask over
half of it); per strategy the median and p99 over all its calls, and per strategy the median over rounds of its
round median divided by naive's. Stop anything else running first. Writes strategy-cost.json (commit, CPU, flags).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.config import StrategyConfig
from bcbench.evaluation.latency_sources import interleaved_request_ms
from bcbench.evaluation.strategies import Strategy
from bcbench.modes import mode_name
from bcbench.policies.checkpoint import configure_runner, load_runner
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run_dir")
    ap.add_argument("--sampler", default="ddim")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--strategies", nargs="+", default=["naive", "rtc"],
                    help="naive, rtc, rtc-no-jacobian (rtc with J = I), bid, ensemble, prefix (a delay-trained run)")
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--calls", type=int, default=5, help="timed requests per strategy and round")
    ap.add_argument("--warmup", type=int, default=10, help="untimed requests per strategy first")
    ap.add_argument("--backend", default="torch", choices=["torch", "openvino", "onnxruntime"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--bid-samples", type=int, default=16, help="bid: N candidates (and as many of the weak policy)")
    ap.add_argument("--bid-weak", default=None, help="bid: the weaker policy's run folder (an early checkpoint)")
    ap.add_argument("--out", default=".")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    runner = load_runner(args.run_dir, use_ema=True)
    configure_runner(runner, args.sampler, args.steps, 0, None)
    apply_mode(runner, mode_name(args.backend, "fp32", False))
    weak = None
    if args.bid_weak:  # run as the policy is: same sampler and mode
        weak = load_runner(args.bid_weak, use_ema=True)
        configure_runner(weak, args.sampler, args.steps, 0, None)
        apply_mode(weak, runner.info.mode)
    # "rtc-no-jacobian": rtc with --rtc-no-jacobian (J = I), timed beside the paper's form
    strategies = {k: Strategy(StrategyConfig(k.split("-")[0], rtc_jacobian=k != "rtc-no-jacobian",
                                             bid_samples=args.bid_samples,
                                             bid_weak=args.bid_weak if k == "bid" else None),
                              runner, weak if k == "bid" else None) for k in args.strategies}
    ms, contention = interleaved_request_ms(runner, strategies, args.rounds, args.calls, args.warmup)
    base = next(iter(strategies))
    out = {"type": "strategy-cost", "run_dir": str(args.run_dir), "sampler": args.sampler, "steps": args.steps,
           "mode": runner.info.mode, "batch": 1, "rounds": args.rounds, "calls_per_round": args.calls,
           "warmup": args.warmup, "relative_to": base, "cpu_contention": contention, "strategies": {},
           **provenance()}
    for k, rounds in ms.items():
        flat = np.array(rounds).ravel()  # (rounds * calls,)
        ratio = np.median([np.median(r) / np.median(b) for r, b in zip(rounds, ms[base], strict=True)])
        out["strategies"][k] = {"median_ms": float(np.median(flat)), "p99_ms": float(np.quantile(flat, 0.99)),
                                "calls": int(flat.size), "ratio_to_first_median_of_rounds": float(ratio),
                                "describe": strategies[k].describe()}
        print(f"{k:10s} median {np.median(flat):7.2f} ms  p99 {np.quantile(flat, 0.99):7.2f} ms  "
              f"x{ratio:.3f} of {base} (median over {args.rounds} rounds)")
    path = Path(args.out) / "strategy-cost.json"
    write_json(path, out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
