"""What torch's own threads cost a policy whose networks a runtime runs: the runner's glue on one torch thread
(bcbench.policies.learned.glue_threads, the default) against the glue on every torch thread, interleaved.

    .venv/bin/python benchmarks/glue_threads.py [--policy cnn_mlp resnet50 bct diffusion] [--mode openvino-fp32
                onnxruntime-fp32] [--rounds 20] [--calls 5] [--threads 2] [--out results/latency-floor-xeon/glue-ab]

Each (policy, mode) is set up once at paper size and timed at batch 1 in rounds; every round times both forms in
turn (--calls calls each, after one warm-up call), so a drifting VM treats them alike. Diffusion Policy runs
DDIM-10. The glue is the torch work around the graphs (observation preparation, normalisation, a sampler's
update); with every torch thread, torch's intra-op workers spin after the glue's parallel element-wise ops on the
cores the runtime's threads use. Stop anything else running first. Writes glue-threads.json (every call's time,
stamped with commit, CPU and threads) and prints a table.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from pathlib import Path

import numpy as np
import torch

import bcbench.policies.learned as learned
from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.benchmark import _normalizer
from bcbench.interface import example_observation
from bcbench.policies import make_policy
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance

ONE_THREAD = learned.glue_threads


def every_thread(_model: object) -> contextlib.AbstractContextManager[None]:
    return contextlib.nullcontext()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--policy", nargs="+", default=["cnn_mlp", "resnet50", "bct", "diffusion"])
    ap.add_argument("--mode", nargs="+", default=["openvino-fp32", "onnxruntime-fp32"])
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--calls", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="results/latency-floor-xeon/glue-ab")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    rows = []
    for name in args.policy:
        for mode in args.mode:
            torch.manual_seed(0)
            model = make_policy(name, "paper").eval()
            runner = learned.PolicyRunner(model, _normalizer())
            apply_mode(runner, mode)
            if model.samplers:
                model.set_sampler("ddim" if "ddim" in model.samplers else model.samplers[0], 10)
            obs = example_observation(1, runner.obs_horizon)
            times: dict[str, list[float]] = {"one torch thread": [], "every torch thread": []}
            for _ in range(args.rounds):
                for form, glue in (("one torch thread", ONE_THREAD), ("every torch thread", every_thread)):
                    learned.glue_threads = glue
                    runner.predict_action_chunk(obs)  # warm-up after the switch
                    for _ in range(args.calls):
                        t0 = time.perf_counter()
                        runner.predict_action_chunk(obs)
                        times[form].append((time.perf_counter() - t0) * 1e3)
            learned.glue_threads = ONE_THREAD
            stats = {f: {"median_ms": float(np.median(t)), "p99_ms": float(np.percentile(t, 99)), "calls": len(t),
                         "ms": t} for f, t in times.items()}
            ratio = stats["one torch thread"]["median_ms"] / stats["every torch thread"]["median_ms"]
            rows.append({"policy": name, "preset": "paper", "mode": mode, "variant": "ddim10" if model.samplers
                         else "default", "forms": stats, "ratio_one_over_every": ratio})
            print(f"{name} {mode}: one torch thread {stats['one torch thread']['median_ms']:.2f} ms, every torch "
                  f"thread {stats['every torch thread']['median_ms']:.2f} ms (x{ratio:.2f})", flush=True)
    write_json(Path(args.out) / "glue-threads.json", {"rounds": args.rounds, "calls_per_round": args.calls,
                                                     "threads": args.threads, "rows": rows, **provenance()})


if __name__ == "__main__":
    main()
