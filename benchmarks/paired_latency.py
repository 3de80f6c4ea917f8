"""Latency ratios that survive a drifting machine: settings timed in interleaved rounds, not one after another.

    .venv/bin/python benchmarks/paired_latency.py [--config cpu] [--steps 1 2 ... 100] [--flow-steps 1 2 4 10]
                [--policies bct resnet50 cnn_mlp] [--rounds 10] [--calls 5] [--mode fast] [--threads 2]
                [--out results/latency-paired-cpu]

A study times each setting in its own block of about 100 calls. On a shared VM whose speed drifts by tens of
percent within minutes, two blocks a few minutes apart can differ by 30% for the same work (the CPU study
timed DP DDPM-10 at 122.6 ms and DDIM-10, four minutes later, at 94.4 ms). Here every setting (Diffusion
Policy DDPM-K and DDIM-K, flow Euler-K and any --policies, at the preset's network size) runs --calls calls in
each of --rounds rounds, in turn, so drift hits all alike; per setting the median over all its calls, and per
pair the median over rounds of the ratio of round medians. Weights are random (they do not change the time of a call).
Several --mode values are timed in the same rounds (every mode's settings in turn), one file per mode:
`latency-paired.json` for reference, `latency-paired-MODE.json` for the others, all stamped with one `run_id`.
Stop anything else running first. A study's report reads `latency-paired*.json` from the study's folder, one
file per mode (copy them there): findings 1 and 3 and Figure 5 use the reference mode's times and ratios, the
few-step section the fast mode's, and the table "which policy for my control loop" the fastest exact mode of the
files that share a run_id (times of one run, so a drifting machine cannot favour a mode or a policy).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from bcbench.evaluation.backends import set_mode
from bcbench.modes import MODES
from bcbench.policies import BCPolicy, make_policy
from bcbench.utils.io import write_json
from bcbench.utils.system import CpuContention, provenance


def settings(config: str, steps: list[int], flow_steps: list[int], mode: str,
             policies: tuple[str, ...] = ()) -> dict[str, tuple]:
    """name -> (model, sampler, K); one model per family, so DDPM and DDIM time the very same weights. Other policies
    (no sampler) under their registry name, as a study's report looks them up (`findings.with_interleaved`)."""
    torch.manual_seed(0)
    dp, flow = make_policy("diffusion", config).eval(), make_policy("flow", config).eval()
    for m in (dp, flow):
        set_mode(m, mode)
    out = {}
    for k in steps:
        out |= {f"ddpm{k}": (dp, "ddpm", k), f"ddim{k}": (dp, "ddim", k)}
    out |= {f"euler{k}": (flow, "euler", k) for k in flow_steps}
    for name in policies:
        model = make_policy(name, config).eval()
        set_mode(model, mode)
        out[name] = (model, None, None)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="cpu")
    ap.add_argument("--steps", type=int, nargs="+", default=[1, 2, 4, 5, 10, 20, 50, 100], help="DDPM and DDIM")
    ap.add_argument("--flow-steps", type=int, nargs="+", default=[1, 2, 4, 10], help="flow Euler")
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--calls", type=int, default=5, help="timed calls per setting and round")
    ap.add_argument("--policies", nargs="*", default=[],
                    help="other policies timed in the same rounds (e.g. bct resnet50 cnn_mlp): finding 1 compares them")
    ap.add_argument("--mode", nargs="+", default=["fast"], choices=MODES,
                    help="inference modes, timed in the same rounds (one output file each)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="results/latency-paired-cpu")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    runs = {mode: settings(args.config, args.steps, args.flow_steps, mode, tuple(args.policies)) for mode in args.mode}
    ms: dict[str, dict[str, list[list[float]]]] = {m: {name: [] for name in r} for m, r in runs.items()}
    run_id = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    with torch.inference_mode(), CpuContention() as contention:  # what else ran meanwhile, and the VM's steal
        for r in range(args.rounds):
            for mode, named in runs.items():
                for name, (model, kind, k) in named.items():
                    ms[mode][name].append(time_calls(model, kind, k, args.calls))
            print(f"round {r + 1}/{args.rounds}", flush=True)
    out = Path(args.out)
    for mode in args.mode:
        median, pairs = summarise(ms[mode], args.steps, args.flow_steps)
        lines = [f"mode {mode}", "", "| setting | median ms |", "|---|---|",
                 *(f"| {n} | {v:.1f} |" for n, v in median.items()), "",
                 "| ratio (median over rounds of round medians) | value |", "|---|---|",
                 *(f"| {n} | {v:.2f} |" for n, v in pairs.items())]
        print("\n".join(lines))
        stem = "latency-paired" if mode == "reference" else f"latency-paired-{mode}"
        write_json(out / f"{stem}.json", {"type": "latency-paired", "config": args.config, "mode": mode,
                                          "run_id": run_id, "interleaved_modes": args.mode,
                                          "rounds": args.rounds, "calls": args.calls, "threads": args.threads,
                                          "median_ms": median, "ratios": pairs, "samples_ms": ms[mode],
                                          "contention": contention.result, **provenance("cpu")})
        (out / f"{stem}.md").write_text("\n".join(lines) + "\n")


def time_calls(model: BCPolicy, kind: str | None, k: int | None, calls: int) -> list[float]:
    """`calls` timed calls at batch 1 (ms), after one warm-up call (the sampler may just have been switched)."""
    if kind:
        model.set_sampler(kind, k)
    obs = model.example_obs(1)
    model.predict_action_chunk(obs)
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        model.predict_action_chunk(obs)
        times.append((time.perf_counter() - t) * 1e3)
    return times


def summarise(ms: dict[str, list[list[float]]], steps: list[int], flow_steps: list[int]
              ) -> tuple[dict[str, float], dict[str, float]]:
    """Per setting the median over all its calls; per pair the median over rounds of the ratio of round medians."""
    median = {name: float(np.median(np.concatenate(v))) for name, v in ms.items()}

    def ratio(a: str, b: str) -> float:
        return float(np.median([np.median(x) / np.median(y) for x, y in zip(ms[a], ms[b], strict=True)]))

    pairs = {}
    for k in steps:
        pairs[f"ddim{k}/ddpm{k}"] = ratio(f"ddim{k}", f"ddpm{k}")
    for k in flow_steps:
        if k in steps:
            pairs[f"euler{k}/ddim{k}"] = ratio(f"euler{k}", f"ddim{k}")
        if 10 in steps:
            pairs[f"euler{k}/ddim10"] = ratio(f"euler{k}", "ddim10")
    return median, pairs


if __name__ == "__main__":
    main()
