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

`correction` (A2C2's head, arXiv 2509.23224) adds work on every control step, not only per request: with
`--correction RUN_DIR` (a trained head on this run) or `--correction untrained` (the `cpu` preset's head built in
memory on this run: a dense MLP and the base's encoder, whose cost does not depend on the weights' values) the hook
is also timed alone at batch 1, `--calls` calls in each round interleaved with the requests, and its median and p99
are written as `per_step_hook`. Its request time is the naive request plus the hook's calls while it computes
(`Strategy.timed_request`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.config import StrategyConfig
from bcbench.evaluation.latency_sources import interleaved_request_ms, timed_request_inputs
from bcbench.evaluation.strategies import Strategy
from bcbench.modes import mode_name
from bcbench.policies.checkpoint import build_model, configure_runner, load_correction, load_runner
from bcbench.policies.config import config_to_dict
from bcbench.policies.correction import CorrectionConfig, CorrectionRunner
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance


def main(argv: list[str] | None = None) -> None:
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
    ap.add_argument("--correction", default=None, metavar="RUN_DIR|untrained",
                    help="correction: the head's run folder, or 'untrained' (the cpu preset's head on RUN_DIR)")
    ap.add_argument("--out", default=".")
    args = ap.parse_args(argv)
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
                                             bid_weak=args.bid_weak if k == "bid" else None,
                                             correction=args.correction if k == "correction" else None),
                              runner, weak if k == "bid" else None,
                              head(runner, args) if k == "correction" else None) for k in args.strategies}
    hooked = [s for s in strategies.values() if s.head is not None]
    between_rounds = None
    if hooked:  # the hook alone at batch 1, interleaved with the requests
        obs, chunk, _ = timed_request_inputs(runner, True)  # (1, Tp, A): the step's planned action is chunk[:, cs]

        def between_rounds() -> None:
            for s in hooked:
                hook_calls(s, obs, chunk, args.calls)

        for s in hooked:
            hook_calls(s, obs, chunk, args.warmup)
            s.step_compute_s.clear()
    ms, contention = interleaved_request_ms(runner, strategies, args.rounds, args.calls, args.warmup, between_rounds)
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
        if strategies[k].head is not None:
            hook = np.array(strategies[k].step_compute_s) * 1e3  # (rounds * calls,)
            out["strategies"][k]["per_step_hook"] = {"median_ms": float(np.median(hook)),
                                                     "p99_ms": float(np.quantile(hook, 0.99)), "calls": int(hook.size),
                                                     "head": strategies[k].head.describe()}
            print(f"{k:10s} per-step hook alone: median {np.median(hook):.2f} ms  p99 {np.quantile(hook, 0.99):.2f} ms "
                  f"over {hook.size} calls at batch 1")
        print(f"{k:10s} median {np.median(flat):7.2f} ms  p99 {np.quantile(flat, 0.99):7.2f} ms  "
              f"x{ratio:.3f} of {base} (median over {args.rounds} rounds)")
    path = Path(args.out) / "strategy-cost.json"
    write_json(path, out)
    print(f"wrote {path}")


def head(runner, args) -> CorrectionRunner:
    """The head the correction strategy runs: a trained one, or the cpu preset's built in memory on the same base run
    (its own copy of the base, as a trained head loads it: the timed runner is left as it is)."""
    if args.correction != "untrained":
        return load_correction(args.correction)
    m = runner.model.config
    cfg = {**config_to_dict(CorrectionConfig.preset("cpu")), "base": str(args.run_dir), "obs_horizon": m.obs_horizon,
           "pred_horizon": m.pred_horizon}
    model = build_model({"policy": "correction", "config": cfg})  # validated as a run's config is
    return CorrectionRunner(model, model.base.normalizer, "untrained (cpu preset, built in memory)")


def hook_calls(s: Strategy, obs: dict, chunk: np.ndarray, n: int) -> None:
    """n per-step hook calls at batch 1 on one observation, the step's planned action at age 0 (timed by `correct`)."""
    cs = s.policy.chunk_start
    for _ in range(n):
        s.correct(obs, chunk[:, cs], np.zeros(1, np.int64), np.full(1, cs, np.int64))


if __name__ == "__main__":
    main()
