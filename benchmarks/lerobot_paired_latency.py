"""A LeRobot policy's call beside bcbench's own, timed in interleaved rounds (one run, one machine).

    .venv/bin/python benchmarks/lerobot_paired_latency.py FOLDER [--rounds 10] [--calls 10] [--threads 2]
        [--out results/lerobot-interop/latency-paired]

Contenders, each at batch 1 on one random observation: the LeRobot folder (through the sidecar worker: its own
compute time, the pipe excluded), and bcbench's quick Diffusion Policy at DDIM-10 in torch (`reference`, as
LeRobot runs) and in OpenVINO fp32 (exact; the mode `--mode auto` picked on this machine). Separate blocks a
few minutes apart drift by tens of percent on a shared VM, so every contender runs --calls calls in each of
--rounds rounds, in turn; per contender the median and p99 over all calls, per pair the median over rounds
of the ratio of round medians. Weights do not change a call's time (bcbench's are random here). Stop anything
else running first.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from bcbench.evaluation.backends import set_mode
from bcbench.interface import example_observation
from bcbench.policies import make_policy
from bcbench.policies.outside import outside_policy
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance


def contenders(folder: str) -> dict[str, tuple[Callable[[], None], Callable[[float], float]]]:
    """name -> (one call, wall seconds -> the seconds to record)."""
    lerobot = outside_policy(f"lerobot:{folder}")
    obs_lr = example_observation(1, lerobot.obs_horizon)
    out = {"lerobot-dp": (lambda: lerobot.predict_action_chunk(obs_lr), lambda wall: lerobot.last_compute_s)}
    for mode in ("reference", "openvino-fp32"):
        torch.manual_seed(0)
        dp = make_policy("diffusion", "quick").eval()
        dp.set_sampler("ddim", 10)
        set_mode(dp, mode)
        obs = dp.example_obs(1)
        out[f"bcbench-dp-{mode}"] = ((lambda m=dp, o=obs: m.predict_action_chunk(o)), lambda wall: wall)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", help="a LeRobot Diffusion Policy folder (pretrained_model)")
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--calls", type=int, default=10, help="timed calls per contender and round")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="results/lerobot-interop/latency-paired")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    runs = contenders(args.folder)
    ms: dict[str, list[list[float]]] = {name: [] for name in runs}
    with torch.inference_mode():
        for call, _ in runs.values():  # warm-up: compile, caches
            for _ in range(3):
                call()
        for r in range(args.rounds):
            for name, (call, seconds) in runs.items():
                times = []
                for _ in range(args.calls):
                    t = time.perf_counter()
                    call()
                    times.append(seconds(time.perf_counter() - t) * 1e3)
                ms[name].append(times)
            print(f"round {r + 1}/{args.rounds}", flush=True)
    flat = {n: np.concatenate(v) for n, v in ms.items()}
    stats = {n: {"median_ms": float(np.median(v)), "p99_ms": float(np.percentile(v, 99)), "calls": int(v.size)}
             for n, v in flat.items()}

    def ratio(a: str, b: str) -> float:
        return float(np.median([np.median(x) / np.median(y) for x, y in zip(ms[a], ms[b], strict=True)]))

    pairs = {f"lerobot-dp/{n}": ratio("lerobot-dp", n) for n in runs if n != "lerobot-dp"}
    lines = ["| contender | median ms | p99 ms | calls |", "|---|---|---|---|",
             *(f"| {n} | {s['median_ms']:.1f} | {s['p99_ms']:.1f} | {s['calls']} |" for n, s in stats.items()), "",
             "| ratio (median over rounds of round medians) | value |", "|---|---|",
             *(f"| {n} | {v:.2f} |" for n, v in pairs.items())]
    print("\n".join(lines))
    out = Path(args.out)
    write_json(out / "latency-paired.json", {"type": "latency-paired", "folder": args.folder, "rounds": args.rounds,
                                             "calls": args.calls, "threads": args.threads, "stats": stats,
                                             "ratios": pairs, "samples_ms": ms, **provenance("cpu")})
    (out / "latency-paired.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
