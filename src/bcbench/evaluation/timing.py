"""Inference latency of one policy call at batch 1: raw observation in, 16x2 chunk out, normalisation included.

Method: warm-up calls, then timed calls until both a minimum count and a minimum time are reached (capped),
`torch.cuda.synchronize()` around every GPU call; median, p90, p99 (from >= 100 calls only; with fewer
the maximum, labelled "max of N"), min and calls/s are reported with the thread count, CPU model, GPU name
and torch version. Real-time verdicts use that tail statistic (a control loop must meet its deadline on
the slow calls too) and name it: at control rate f, re-planning every 8 actions needs p99 <= 8/f,
re-planning every step needs p99 <= 1/f.

Modes (bcbench.evaluation.backends): `reference` is fp32 eager PyTorch the way the public code runs it (Diffusion
Policy: the plain U-Net at every step); `fast` is the torch default (split FiLM); `openvino-fp32|bf16|int8|int8w`
run the same graphs compiled by OpenVINO. Exact forms equal the reference within 1e-4 (tested).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
import torch

from bcbench.errors import BCBenchError
from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.floor import against_floor, call_work, machine_limits
from bcbench.interface import ChunkPolicy, SelfTimedPolicy
from bcbench.policies.learned import PolicyRunner
from bcbench.tasks import example_for, task_of
from bcbench.utils.system import CpuContention, provenance

ACTION_HORIZON = 8


@dataclass
class TimingConfig:
    warmup: int = 3
    """untimed calls first (allocator, caches, lazy initialisation)"""
    min_calls: int = 100
    """timed calls at least (100 are needed for a p99; slow rows stop at max_seconds and report a maximum)"""
    min_seconds: float = 2.0
    """keep timing until this much time has passed (for a stable median)"""
    max_calls: int = 200
    """timed calls at most"""
    max_seconds: float = 30.0
    """stop timing after this long even if min_calls is not reached (very slow rows: 'max of N')"""

    def __post_init__(self) -> None:
        if self.min_calls < 1 or self.max_calls < self.min_calls or self.warmup < 0:
            raise BCBenchError("need warmup >= 0 and 1 <= min_calls <= max_calls")


def time_calls(fn: Callable[[], object], cfg: TimingConfig, cuda: bool = False,
               clock: Callable[[], float] | None = None, what: str = ""
               ) -> dict[str, Any]:
    """Time `fn()`; returns statistics in milliseconds, and what else used the CPUs meanwhile (`cpu_contention`;
    a warning on stderr naming `what` when the machine was not quiet, none when `what` is empty). `clock()`, where
    given, returns the call's own compute seconds (a policy in another process reports them) and replaces the wall
    time."""
    def once() -> float:
        if cuda:
            torch.cuda.synchronize()
        t = time.perf_counter()
        fn()
        if cuda:
            torch.cuda.synchronize()
        return clock() if clock is not None else time.perf_counter() - t

    for i in range(cfg.warmup):
        if once() > 1.0 and i == 0:
            break  # a call of over a second is its own warm-up; more would only cost minutes
    times: list[float] = []
    with CpuContention() as contention:
        start = time.perf_counter()
        while len(times) < cfg.max_calls:
            times.append(once())
            elapsed = time.perf_counter() - start
            if len(times) >= cfg.min_calls and elapsed >= cfg.min_seconds:
                break
            if elapsed >= cfg.max_seconds and len(times) >= 3:
                break
    if what:
        contention.warn(what)
    return {**summarize_ms(np.array(times) * 1e3), "cpu_contention": contention.result}


MIN_CALLS_FOR_PERCENTILES = 100


def summarize_ms(ms: np.ndarray) -> dict[str, Any]:
    """Statistics of call times in ms. The tail statistic is the p99 from >= 100 calls, else the maximum.

    Below 100 calls a p99 is just the largest value under another name, so p90 and p99 are reported only
    from at least 100 calls; with fewer, `tail_stat` reads "max of N". The median is always reported.
    """
    n = int(ms.size)
    out: dict[str, Any] = {"median_ms": float(np.median(ms)), "min_ms": float(ms.min()), "max_ms": float(ms.max()),
                           "mean_ms": float(ms.mean()), "calls": n, "calls_per_s": float(1e3 / np.median(ms)),
                           "samples_ms": [round(float(v), 4) for v in ms]}  # for draws in real-time evaluation
    if n >= MIN_CALLS_FOR_PERCENTILES:
        out.update(p90_ms=float(np.percentile(ms, 90)), p99_ms=float(np.percentile(ms, 99)), tail_stat="p99")
        out["tail_ms"] = out["p99_ms"]
    else:
        out.update(p90_ms=None, p99_ms=None, tail_stat=f"max of {n}", tail_ms=out["max_ms"])
    return out


def verdicts(tail_ms: float, rate_hz: float, action_horizon: int = ACTION_HORIZON,
             tail_stat: str = "p99") -> dict[str, Any]:
    """Real-time verdicts at `rate_hz` and the largest control rates sustained, from the tail statistic."""
    s = tail_ms / 1e3
    return {
        "rate_hz": rate_hz,
        "action_horizon": action_horizon,  # the chunked verdict's re-plan interval, in steps
        "verdict_statistic": tail_stat,  # "p99" (>= 100 calls) or "max of N"
        "realtime_chunked": s <= action_horizon / rate_hz,  # re-plan every action_horizon steps
        "realtime_every_step": s <= 1.0 / rate_hz,  # re-plan at every control step
        "max_rate_chunked_hz": action_horizon / s if s > 0 else float("inf"),
        "max_rate_every_step_hz": 1.0 / s if s > 0 else float("inf"),
    }


def measure_runner(runner: ChunkPolicy, cfg: TimingConfig, rate_hz: float = 10.0, what: str = "") -> dict[str, Any]:
    """Time `runner.predict_action_chunk` on a batch-1 raw observation."""
    obs = example_for(runner)
    out = runner.predict_action_chunk(obs)
    want = (1, runner.pred_horizon, task_of(runner).action_dim)
    if np.asarray(out).shape != want:
        raise BCBenchError(f"{runner.name} returned {np.asarray(out).shape}, expected {want}")
    cuda = getattr(runner, "device", torch.device("cpu")).type == "cuda"
    clock = self_clock(runner)
    # a self-timed policy's worker process is "other" CPU use: recorded, not warned about
    stats = time_calls(lambda: runner.predict_action_chunk(obs), cfg, cuda, clock,
                       what=(what or runner.name) if clock is None else "")
    if clock is not None:  # what the pipe adds, for the record (not in the latency)
        wall = time_calls(lambda: runner.predict_action_chunk(obs), TimingConfig(warmup=0, min_calls=20,
                                                                                min_seconds=0.0, max_calls=20))
        stats["timed_as"] = "compute time reported by the policy's process (pipe excluded)"
        stats["wall_median_ms_with_pipe"] = wall["median_ms"]
    return {**stats, **verdicts(stats["tail_ms"], rate_hz, runner.action_horizon, stats["tail_stat"])}


def self_clock(runner: object) -> Callable[[], float] | None:
    """For a policy that times itself (`SelfTimedPolicy`), the function that reads its last call's seconds."""
    return (lambda: runner.last_compute_s) if isinstance(runner, SelfTimedPolicy) else None


def latency_record(policy: ChunkPolicy, cfg: TimingConfig, rate_hz: float = 10.0,
                   modes: tuple[str, ...] = ("reference", "fast")) -> dict[str, Any]:
    """Time a policy in each mode (baselines have one); a JSON-ready record with provenance."""
    out: dict[str, Any] = {"type": "latency", "created": datetime.now(UTC).isoformat(timespec="seconds"),
                           "policy": policy.describe(), "batch": 1, "timing": cfg.__dict__, "modes": {}}
    device = str(getattr(policy, "device", "cpu"))
    if not isinstance(policy, PolicyRunner):
        out["modes"]["reference"] = measure_runner(policy, cfg, rate_hz)
    else:
        before = policy.info.mode or "fast"
        for mode in modes:  # the same runner in each form, one after the other
            apply_mode(policy, mode)
            # this machine's floor (bcbench.evaluation.floor): its limits measured right before each mode
            limits = machine_limits() if device == "cpu" else None
            stats = measure_runner(policy, cfg, rate_hz, what=f"{policy.name} ({mode})")
            work = {"machine_limits": limits, **call_work(policy)} if limits else {}
            out["modes"][mode] = {**stats, "deployment": policy.model.deployment, **work}
        out["machine_limits"] = against_floor(list(out["modes"].values()))  # each mode against the best limits
        apply_mode(policy, before)
    return {**out, **provenance(device)}
