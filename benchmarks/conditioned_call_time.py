"""A delay-conditioned network's call against the plain network's, interleaved (issue 76's "<= 1.05x naive's call").

    .venv/bin/python benchmarks/conditioned_call_time.py --pair dp models/diffusion-cpu RUN_DIR ddim \
        --pair flow models/flow-cpu RUN_DIR euler [--steps 10] [--rounds 20] [--calls 5] --out FILE.json

Training-time delay conditioning (`delay_train`) adds a mask channel to the U-Net's input; `--strategy prefix`
re-imposes the clean prefix at every network call (its own cost: benchmarks/strategy_cost.py --strategies naive
prefix). This times plain naive requests of the two networks, same preset, torch fast fp32, batch 1, in turn: per
round each makes --calls calls after 3 warm-up calls each; per pair the median and p99 over all calls and the
median over rounds of the round medians' ratio. The conditioned run's weights need not be trained (a call's cost
does not depend on them). Stop anything else running first.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from bcbench.evaluation.backends import apply_mode
from bcbench.policies.checkpoint import configure_runner, load_runner
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pair", nargs=4, action="append", required=True,
                    metavar=("NAME", "PLAIN", "CONDITIONED", "SAMPLER"))
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--calls", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    obs = {"image": rng.integers(0, 255, (1, 2, 96, 96, 3), dtype=np.uint8),
           "agent_pos": rng.uniform(0, 512, (1, 2, 2)).astype(np.float32)}
    results = {}
    for name, plain, conditioned, sampler in args.pair:
        runners = {}
        for tag, folder in (("plain", plain), ("conditioned", conditioned)):
            runner = load_runner(folder)
            configure_runner(runner, sampler, args.steps, 0, None)
            apply_mode(runner, "fast")
            runners[tag] = runner
        ms: dict[str, list[float]] = {k: [] for k in runners}
        ratios = []
        for _ in range(args.rounds):
            med = {}
            for tag, runner in runners.items():
                for _ in range(3):
                    runner.predict_action_chunk(obs)
                calls = []
                for _ in range(args.calls):
                    t0 = time.perf_counter()
                    runner.predict_action_chunk(obs)
                    calls.append(1000 * (time.perf_counter() - t0))
                ms[tag] += calls
                med[tag] = float(np.median(calls))
            ratios.append(med["conditioned"] / med["plain"])
        results[name] = {tag: {"median_ms": float(np.median(v)), "p99_ms": float(np.percentile(v, 99)),
                               "calls": len(v), "folder": runners[tag].info.run_dir,
                               "weights_sha256": runners[tag].info.weights_sha256} for tag, v in ms.items()}
        results[name]["conditioned_over_plain"] = float(np.median(ratios))
        print(f"{name}: plain {results[name]['plain']['median_ms']:.2f} ms, conditioned "
              f"{results[name]['conditioned']['median_ms']:.2f} ms, x{results[name]['conditioned_over_plain']:.3f} "
              "(median over rounds)")
    write_json(args.out, {"type": "conditioned-call-time", "rounds": args.rounds, "calls": args.calls,
                          "threads": args.threads, "results": results, **provenance("cpu")})


if __name__ == "__main__":
    main()
