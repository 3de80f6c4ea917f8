"""Does `--backend auto`'s trial time each exact mode as the latency table does? Each mode alone against the same
mode inside an interleaved trial: the trial as it was (7 rounds in a fixed order, 1 warm-up call after each switch,
3 timed calls) and as it is (bcbench.evaluation.auto.pick_fastest: rotated order, 3 warm-up calls, 10 timed), at
paper size, batch 1.

    .venv/bin/python benchmarks/auto_order.py [--policy resnet50 bct cnn_mlp] [--alone 60] [--repeats 3]
                [--threads 2] [--out results/latency-floor-xeon/auto-order]

Why: on the Intel Xeon (avx512_bf16) `auto` chose ONNX Runtime for ResNet-50 (trial: OpenVINO 10.96 ms, ONNX
Runtime 10.85) while the same run's OpenVINO row, timed alone, was 15% faster than ONNX Runtime's. Each policy's
three modes are set up once (as `choose_mode` does); then, `--repeats` times, in turn: every mode alone (`--alone`
calls after 3 warm-up calls), the old trial and the new one. Stop anything else running first. Writes
auto-order.json (every median and choice, stamped with commit, CPU and threads) and prints a table.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from bcbench.evaluation.auto import CANDIDATES, mode_state, pick_fastest, restore_state
from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.benchmark import _normalizer
from bcbench.interface import example_observation
from bcbench.policies import make_policy
from bcbench.policies.learned import PolicyRunner
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance


def old_trial(switch: Callable[[str], None], call: Callable[[], object], rounds: int = 7,
              calls: int = 3) -> dict[str, float]:
    """The trial before the change: a fixed order, one warm-up call after each switch."""
    samples: dict[str, list[float]] = {m: [] for m in CANDIDATES}
    for _ in range(rounds):
        for m in CANDIDATES:
            switch(m)
            call()
            for _ in range(calls):
                t0 = time.perf_counter()
                call()
                samples[m].append((time.perf_counter() - t0) * 1e3)
    return {m: float(np.median(v)) for m, v in samples.items()}


def alone(switch: Callable[[str], None], call: Callable[[], object], mode: str, n: int) -> float:
    """The mode's median call timed alone: `n` calls after 3 warm-up calls (a one-setup trial of one round)."""
    return pick_fastest({mode: lambda: switch(mode)}, call, rounds=1, calls=n, warm=3)[1][mode]


def measure(name: str, repeats: int, n_alone: int) -> list[dict[str, object]]:
    torch.manual_seed(0)
    runner = PolicyRunner(make_policy(name, "paper").eval(), _normalizer())
    prepared = {}
    for m in CANDIDATES:
        apply_mode(runner, m)
        prepared[m] = mode_state(runner)

    def switch(m: str) -> None:
        restore_state(runner, prepared[m])

    obs = example_observation(1, runner.obs_horizon)

    def call() -> None:
        runner.predict_action_chunk(obs)

    rows = []
    for rep in range(repeats):
        row = {"policy": name, "repeat": rep, "alone": {m: alone(switch, call, m, n_alone) for m in CANDIDATES},
               "old trial": old_trial(switch, call),
               "new trial": pick_fastest({m: (lambda m=m: switch(m)) for m in CANDIDATES}, call)[1]}
        for form in ("alone", "old trial", "new trial"):
            row[f"{form} chooses"] = min(row[form], key=row[form].__getitem__)
        rows.append(row)
        print(name, rep, "  ".join(f"{form}: " + ", ".join(f"{m} {row[form][m]:.2f}" for m in CANDIDATES)
                                    + f" -> {row[form + ' chooses']}" for form in ("alone", "old trial", "new trial")),
              flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--policy", nargs="+", default=["resnet50", "bct", "cnn_mlp"])
    ap.add_argument("--alone", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="results/latency-floor-xeon/auto-order")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    rows = [row for name in args.policy for row in measure(name, args.repeats, args.alone)]
    write_json(Path(args.out) / "auto-order.json", {"alone_calls": args.alone, "threads": args.threads,
                                                   "rows": rows, **provenance()})


if __name__ == "__main__":
    main()
