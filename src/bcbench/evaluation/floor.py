"""How far a call is from what this machine allows: the floor of one policy call, measured in the same run.

A call must at least read the weights it uses (from memory, once per use: a denoising loop reads the U-Net once
per step) and do its arithmetic. This module counts both for one batch-1 call of the policy as it runs (hooks on
every module record the parameter bytes each use reads; torch's FLOP counter counts the matrix products and
convolutions), measures this machine's streaming read bandwidth and matrix-product throughput with the threads the
call uses, and states

    floor = max(bytes / bandwidth, FLOPs / throughput)

so a latency record says "x times the floor" instead of a bare number. When the weights fit in the CPU's cache
(the small networks) the byte term over-counts memory traffic, and the floor is then a rough lower bound only.

On a shared VM the limits measured at one moment swing by a factor of two (a neighbour's burst), so each
measurement is the best of several trials (STREAM's convention: contention only ever slows a trial), it is
repeated beside every timed row or mode, and the floor of every row uses the best limits the run measured:
"x floor" is then the distance from what this machine showed it can do, never flattered by a slow moment.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import torch
from torch.utils.flop_counter import FlopCounterMode

from bcbench.policies.learned import PolicyRunner
from bcbench.tasks import example_for

READ_MB = 256  # bytes streamed per bandwidth sample: well past any L3 cache
GEMM_N = 1024


def wall_times(fn: Callable[[], object], n: int) -> list[float]:
    """Wall times of n calls of `fn()` in seconds, after one warm-up call."""
    fn()
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return ts


def machine_limits() -> dict[str, float]:
    """Streaming read bandwidth (GB/s: a sum over a buffer larger than any cache) and fp32 matrix-product
    throughput (GFLOP/s: a 1024^3 product), with torch's current threads; each the best of 9 trials."""
    buf = torch.ones(READ_MB * 2**20 // 4)
    read_s = min(wall_times(lambda: buf.sum(), 9))
    a, b = torch.randn(GEMM_N, GEMM_N), torch.randn(GEMM_N, GEMM_N)
    gemm_s = min(wall_times(lambda: a @ b, 9))
    return {"read_gb_per_s": buf.numel() * 4 / read_s / 1e9, "gemm_gflop_per_s": 2 * GEMM_N**3 / gemm_s / 1e9,
            "threads": torch.get_num_threads()}


def layer_work(runner: PolicyRunner) -> list[dict[str, Any]]:
    """Per module, over one batch-1 call of the runner's torch model in its current torch form (the exported graphs
    are the same): the bytes of the module's own parameters, read once per use (a denoising loop reads the U-Net
    once per step), and the FLOPs of its own forward outside its child modules' calls (torch's FLOP counter: matrix
    products and convolutions); FLOPs outside every module go to "(outside modules)". `call_work` sums them; the
    per-layer roofline (`layer_floor_ms`) takes each module's own max."""
    model = runner.model
    names = {id(m): n or type(m).__name__ for n, m in model.named_modules()}
    per: dict[str, dict[str, float]] = {}
    stack: list[list[float]] = []  # per open module call: [FLOPs counted when it started, FLOPs of its children]
    counter = FlopCounterMode(display=False)

    def pre(module: torch.nn.Module, _args: Any) -> None:
        stack.append([counter.get_total_flops(), 0.0])

    def post(module: torch.nn.Module, _args: Any, _out: Any) -> None:
        start, children = stack.pop()
        inclusive = counter.get_total_flops() - start
        if stack:
            stack[-1][1] += inclusive
        row = per.setdefault(names[id(module)], {"weight_bytes": 0.0, "flops": 0.0})
        row["weight_bytes"] += sum(p.numel() * p.element_size() for p in module.parameters(recurse=False))
        row["flops"] += inclusive - children

    hooks = [h for m in model.modules() for h in (m.register_forward_pre_hook(pre), m.register_forward_hook(post))]
    obs = example_for(runner)
    deployed, model.deployed = model.deployed, None
    try:
        with counter:
            model.reset_noise(0)
            runner.predict_action_chunk(obs)
    finally:
        model.deployed = deployed
        for h in hooks:
            h.remove()
    outside = counter.get_total_flops() - sum(r["flops"] for r in per.values())
    rows = [{"module": n, **r} for n, r in per.items() if r["weight_bytes"] or r["flops"]]
    return rows + ([{"module": "(outside modules)", "weight_bytes": 0.0, "flops": float(outside)}] if outside else [])


def work_totals(layers: list[dict[str, Any]]) -> dict[str, float]:
    """The whole call's weight bytes and FLOPs from `layer_work`'s modules."""
    return {key: float(sum(x[key] for x in layers)) for key in ("weight_bytes", "flops")}


def call_work(runner: PolicyRunner) -> dict[str, float]:
    """Weight bytes read and FLOPs of one batch-1 call of the runner's torch model in its current torch form."""
    return work_totals(layer_work(runner))


def layer_floor_ms(layers: list[dict[str, Any]], limits: dict[str, float]) -> float:
    """The per-layer roofline: the sum over modules of max(bytes / bandwidth, FLOPs / throughput). A runtime that
    runs the layers one after another cannot overlap one layer's arithmetic with another's weight reads, so this is
    the floor for layer-by-layer execution; `floor_ms`'s max over the whole call assumes perfect overlap."""
    return sum(max(r["weight_bytes"] / (limits["read_gb_per_s"] * 1e9), r["flops"] / (limits["gemm_gflop_per_s"]
                                                                                   * 1e9)) for r in layers) * 1e3


def floor_ms(work: dict[str, float], limits: dict[str, float]) -> dict[str, float]:
    """The floor of one call in ms, and which limit sets it."""
    mem = work["weight_bytes"] / (limits["read_gb_per_s"] * 1e9) * 1e3
    compute = work["flops"] / (limits["gemm_gflop_per_s"] * 1e9) * 1e3
    return {"floor_ms": max(mem, compute), "memory_ms": mem, "compute_ms": compute,
            "bound": "memory" if mem >= compute else "compute"}


def best_limits(measured: list[dict[str, float]]) -> dict[str, float]:
    """The highest bandwidth and throughput among a run's measurements: what this machine showed it can do."""
    return {"read_gb_per_s": max(m["read_gb_per_s"] for m in measured),
            "gemm_gflop_per_s": max(m["gemm_gflop_per_s"] for m in measured), "threads": measured[0]["threads"]}


def against_floor(entries: list[dict[str, Any]]) -> dict[str, float] | None:
    """Give every timed entry that carries its own `machine_limits` and work (`call_work`) the floor under the
    run's best limits, and its median's ratio to it, in place; returns those limits (None: nothing measured)."""
    timed = [e for e in entries if e.get("machine_limits")]
    if not timed:
        return None
    best = best_limits([e["machine_limits"] for e in timed])
    for e in timed:
        e.update(floor_ms(e, best))
        e["x_floor"] = e["median_ms"] / e["floor_ms"] if e["floor_ms"] > 0 else None
    return best
