"""`--backend auto`: the fastest exact inference mode for this checkpoint on this CPU, found by a short trial.

Which exact runtime is fastest differs by CPU (OpenVINO fp32 was at the memory floor on an Intel Xeon with AMX;
a plain ONNX Runtime export beat it on an AMD EPYC Zen 3) and by batch, so bcbench measures instead of guessing:
each exact mode (torch fast, OpenVINO fp32, ONNX Runtime fp32) is set up once and timed at batch 1 in interleaved
rounds (every round calls each mode in turn, so a drifting machine treats them alike); the mode with the lowest
median wins. The choice and its evidence are cached beside the run's exports, keyed by the checkpoint, the
sampler, the CPU model and ISA flags, threads and library versions, and recorded in every result (`deployment`).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bcbench.interface import FilmSplittable
from bcbench.modes import EXACT_MODES
from bcbench.policies.checkpoint import weights_file
from bcbench.policies.learned import PolicyRunner
from bcbench.tasks import example_for
from bcbench.utils.io import read_json, write_json
from bcbench.utils.system import cpu_record, versions

CANDIDATES = tuple(m for m in EXACT_MODES if m != "reference")  # reference is the slow form by design
# Three warm-up calls after each switch: with one, the next calls still ran slow (OpenVINO's by up to 25% at paper
# size on an Intel Xeon, avx512_bf16), and a trial of 7 rounds x 3 calls once chose ONNX Runtime for ResNet-50 where
# OpenVINO was 15% faster in steady state (benchmarks/auto_order.py, results/latency-floor-xeon/auto-order/).
ROUNDS, WARM, CALLS = 3, 3, 10


def pick_fastest(setups: dict[str, Callable[[], None]], call: Callable[[], Any], rounds: int = ROUNDS,
                 calls: int = CALLS, warm: int = WARM) -> tuple[str, dict[str, float]]:
    """The name of the fastest setup and each one's median call in ms. `setups[name]()` puts the policy in that
    form, `call()` runs it once; every round warms each setup with `warm` calls (what a switch leaves cold: caches,
    a runtime's sleeping threads), then times `calls` calls. Round r starts at setup r mod n, so each setup follows
    each other one equally often and whatever one leaves behind does not always fall on the same next one."""
    names = list(setups)
    samples: dict[str, list[float]] = {name: [] for name in names}
    for r in range(rounds):
        for name in names[r % len(names):] + names[:r % len(names)]:
            setups[name]()
            for _ in range(warm):  # the calls after switching pay for the switch, not the mode
                call()
            for _ in range(calls):
                t0 = time.perf_counter()
                call()
                samples[name].append((time.perf_counter() - t0) * 1e3)
    medians = {name: float(np.median(v)) for name, v in samples.items()}
    return min(medians, key=medians.__getitem__), medians


def mode_state(runner: PolicyRunner) -> tuple[Any, ...]:
    """What a mode sets on a runner (bcbench.evaluation.backends.set_mode and apply_mode)."""
    m = runner.model
    split = m.split_film if isinstance(m, FilmSplittable) else None
    return m.deployed, m.deployment, split, runner.info.mode, runner.info.deployment


def restore_state(runner: PolicyRunner, state: tuple[Any, ...]) -> None:
    m = runner.model
    m.deployed, m.deployment, split, runner.info.mode, runner.info.deployment = state
    if split is not None:
        m.split_film = split


def _cache_key(runner: PolicyRunner, candidates: tuple[str, ...] = CANDIDATES) -> str:
    info = runner.info
    ckpt = (Path(info.run_dir) / "checkpoints" / info.checkpoint) if info.run_dir and info.checkpoint else None
    stat = ""
    if ckpt is not None:
        f = weights_file(ckpt, info.weights)
        stat = f"{f}:{f.stat().st_size}:{f.stat().st_mtime_ns}" if f.exists() else str(f)
    blob = json.dumps([stat, runner.name, info.sampler, info.steps, info.spacing, cpu_record(),
                       torch.get_num_threads(), versions(), candidates, (ROUNDS, WARM, CALLS)], sort_keys=True,
                      default=str)  # a changed trial chooses anew
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def choose_mode(runner: PolicyRunner, apply: Callable[[PolicyRunner, str], None],
                candidates: tuple[str, ...] = CANDIDATES, restriction: str = "") -> dict[str, Any]:
    """The fastest exact mode for this runner here (cached per checkpoint, sampler and machine): a record with the
    chosen mode, every candidate's median ms and why. `apply(runner, mode)` switches the runner's mode.
    `candidates`: the exact modes the caller can use (a sweep with Real-Time Chunking needs autograd: torch only),
    `restriction` says why they are fewer than all."""
    unknown = set(candidates) - set(CANDIDATES)
    if not candidates or unknown:
        raise ValueError(f"auto chooses among {CANDIDATES}, not {sorted(unknown) or 'nothing'}")
    cache = None
    if runner.info.run_dir:
        cache = Path(runner.info.run_dir) / "export" / f"auto-{_cache_key(runner, candidates)}.json"
        if cache.exists():
            return {**read_json(cache), "cached": True}
    obs = example_for(runner)
    prepared = {}
    for m in candidates:  # export and compile each mode once; the rounds then only switch between them
        apply(runner, m)
        prepared[m] = mode_state(runner)
    chosen, medians = pick_fastest({m: (lambda m=m: restore_state(runner, prepared[m])) for m in candidates},
                                   lambda: runner.predict_action_chunk(obs))
    why = (f"lowest median of {ROUNDS} interleaved rounds x {CALLS} calls (after {WARM} warm-up calls each) at "
           "batch 1 among the exact modes")
    record = {"chosen": chosen, "median_ms": medians, "rounds": ROUNDS, "warm_calls": WARM, "calls_per_round": CALLS,
              "batch": 1,
              "why": why + (f" {', '.join(candidates)} ({restriction})" if restriction else ""),
              **cpu_record(), "threads": torch.get_num_threads()}
    if cache is not None:
        write_json(cache, record)
    return {**record, "cached": False}
