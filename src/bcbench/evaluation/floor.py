"""How far a call is from what this machine allows: the floor of one policy call, measured in the same run.

A call must at least read the weights it uses (from memory, once per use: a denoising loop reads the U-Net once
per step) and do its arithmetic. This module counts both for one batch-1 call of the policy as it runs (hooks on
every module record the parameter bytes each use reads; torch's FLOP counter counts the matrix products and
convolutions), measures this machine's streaming read bandwidth and matrix-product throughput with the threads the
call uses, and states

    floor = max(bytes / bandwidth, FLOPs / throughput)

so a latency record says "x times the floor" instead of a bare number. When the weights fit in the CPU's cache
(the small networks) the byte term over-counts memory traffic, and the floor is then a rough lower bound only.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from bcbench.interface import example_observation
from bcbench.policies.learned import PolicyRunner

READ_MB = 256  # bytes streamed per bandwidth sample: well past any L3 cache
GEMM_N = 1024


def median_s(fn: Any, n: int = 7) -> float:
    """Median wall time of `fn()` in seconds over n calls, after one warm-up call."""
    fn()
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def machine_limits() -> dict[str, float]:
    """Streaming read bandwidth (GB/s: a sum over a buffer larger than any cache) and fp32 matrix-product
    throughput (GFLOP/s: a 1024^3 product), with torch's current threads."""
    buf = torch.ones(READ_MB * 2**20 // 4)
    read_s = median_s(lambda: buf.sum())
    a, b = torch.randn(GEMM_N, GEMM_N), torch.randn(GEMM_N, GEMM_N)
    gemm_s = median_s(lambda: a @ b)
    return {"read_gb_per_s": buf.numel() * 4 / read_s / 1e9, "gemm_gflop_per_s": 2 * GEMM_N**3 / gemm_s / 1e9,
            "threads": torch.get_num_threads()}


def call_work(runner: PolicyRunner) -> dict[str, float]:
    """Weight bytes read and FLOPs of one batch-1 call of the runner's torch model in its current torch form."""
    model = runner.model
    read = [0]

    def count(module: torch.nn.Module, _args: Any) -> None:
        read[0] += sum(p.numel() * p.element_size() for p in module.parameters(recurse=False))

    hooks = [m.register_forward_pre_hook(count) for m in model.modules()]
    obs = example_observation(1, runner.obs_horizon)
    deployed, model.deployed = model.deployed, None  # count the torch graphs (the exported ones are the same)
    try:
        with FlopCounterMode(display=False) as flops:
            model.reset_noise(0)
            runner.predict_action_chunk(obs)
    finally:
        model.deployed = deployed
        for h in hooks:
            h.remove()
    return {"weight_bytes": float(read[0]), "flops": float(flops.get_total_flops())}


def floor_ms(work: dict[str, float], limits: dict[str, float]) -> dict[str, float]:
    """The floor of one call in ms, and which limit sets it."""
    mem = work["weight_bytes"] / (limits["read_gb_per_s"] * 1e9) * 1e3
    compute = work["flops"] / (limits["gemm_gflop_per_s"] * 1e9) * 1e3
    return {"floor_ms": max(mem, compute), "memory_ms": mem, "compute_ms": compute,
            "bound": "memory" if mem >= compute else "compute"}


def floor_of(runner: PolicyRunner, median_ms: float, limits: dict[str, float]) -> dict[str, Any]:
    """A timed call's floor on this machine: the work of the runner's call, the floor, and median / floor."""
    work = call_work(runner)
    floor = {**work, **floor_ms(work, limits)}
    return {**floor, "x_floor": median_ms / floor["floor_ms"] if floor["floor_ms"] > 0 else None}
