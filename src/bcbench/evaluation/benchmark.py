"""`bcbench latency`: every registered policy at paper and quick size in every inference mode, batch 1.

Latency does not depend on the weights' values, so untrained models with an identity-range normalizer
are timed. Diffusion Policy is timed for each sampler and step count. Output: latency.json, a Markdown
table (also printed), and a log-scale bar chart with the real-time budget lines.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from bcbench.data.normalizer import MinMaxNormalizer
from bcbench.errors import BCBenchError
from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.floor import against_floor, call_work, floor_ms, machine_limits
from bcbench.evaluation.timing import TimingConfig, measure_runner, verdicts
from bcbench.modes import AUTO, EXACT_MODES, MODES
from bcbench.policies import REGISTRY, is_learned, make_policy
from bcbench.policies.learned import PolicyRunner
from bcbench.policies.outside import outside_policy
from bcbench.tasks import Task, get_task, task_of
from bcbench.utils.device import pick_device
from bcbench.utils.io import atomic_path, write_json
from bcbench.utils.system import provenance

DEFAULT_STEPS = (1, 2, 5, 10, 20, 50, 100)


def _normalizer(task: Task | None = None) -> MinMaxNormalizer:
    """An untrained network's normaliser: the task's ranges (default Push-T: its 512 px world for both)."""
    task = task or get_task()
    lo, hi = task.state_range
    state = np.array([[lo] * task.state_dim, [hi] * task.state_dim])
    return MinMaxNormalizer.fit({"agent_pos": state, "action": np.array([task.action_low, task.action_high])})


def _rows_for(name: str, preset: str, modes: list[str], samplers: list[str], steps: list[int], device: torch.device,
              timing: TimingConfig, rate_hz: float, task: Task) -> list[dict[str, Any]]:
    torch.manual_seed(0)
    model = make_policy(name, preset, task)
    if not is_learned(name):
        stats = measure_runner(model, timing, rate_hz)
        return [{"policy": name, "preset": "-", "mode": "reference", "variant": "default", "params": 0, **stats}]
    kinds = [s for s in samplers if s in model.samplers] or list(model.samplers[:1])
    variants = [(s, k) for s in kinds for k in steps] if model.samplers else [(None, None)]
    rows = []
    runner = PolicyRunner(model, _normalizer(task), device)
    for mode in modes:  # outer: each mode exports and compiles once, for every sampler setting
        apply_mode(runner, mode)
        for sampler, k in variants:
            if sampler:
                model.set_sampler(sampler, k)
            model.reset_noise(0)
            # this machine's limits right before the row is timed (a shared VM drifts by tens of percent in minutes)
            limits = machine_limits() if device.type == "cpu" else None
            stats = measure_runner(runner, timing, rate_hz)
            # what this call must read and compute, and this machine's limits beside it (the floor: at the end)
            against = {"machine_limits": limits, **call_work(runner)} if limits else {}
            rows.append({"policy": name, "preset": preset, "mode": mode, "variant": f"{sampler}{k}" if sampler else
                         "default", "params": model.num_parameters(), "deployment": runner.info.deployment or
                         model.deployment, **stats, **against})
    return rows


def _checkpoint_rows(path: str, runner: PolicyRunner, modes: list[str], device: torch.device, timing: TimingConfig,
                     rate_hz: float) -> list[dict[str, Any]]:
    """A trained run's rows: the runner in each mode, in its own sampler setting, with this machine's floor."""
    info, rows = runner.info, []
    for mode in modes:
        apply_mode(runner, mode)
        runner.model.reset_noise(0)
        limits = machine_limits() if device.type == "cpu" else None
        stats = measure_runner(runner, timing, rate_hz)
        against = {"machine_limits": limits, **call_work(runner)} if limits else {}
        rows.append({"policy": runner.name, "preset": info.preset or "-", "mode": mode, "checkpoint": path,
                     "variant": f"{info.sampler}{info.steps}" if info.sampler else "default",
                     "params": runner.model.num_parameters(), "deployment": runner.info.deployment, **stats,
                     **against})
    return rows


def _opt(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}"


def _tail(r: dict[str, Any]) -> str:
    """The tail statistic with its name: '12.30 (p99)' or '950.1 (max of 35)'."""
    stat = r.get("tail_stat", "p99")
    return f"{r.get('tail_ms', r.get('p99_ms')):.2f} ({stat})"


def _table(rows: list[dict[str, Any]], rate_hz: float = 10.0) -> str:
    ref = {(r["policy"], r["preset"], r["variant"]): r["median_ms"] for r in rows if r["mode"] == "reference"}
    head = ("| policy | preset | variant | mode | params | median ms | p90 | tail (p99, or max of N < 100 calls) | min "
            f"| calls/s | speed-up | {rate_hz:g} Hz chunked | {rate_hz:g} Hz every step | max Hz every step "
            "| floor ms (bound) | x floor |")
    lines = [head, "|" + "---|" * 16]
    for r in rows:
        base = ref.get((r["policy"], r["preset"], r["variant"]))
        speed = f"{base / r['median_ms']:.2f}x" if base and r["mode"] != "reference" else "-"
        lines.append(f"| {r['policy']} | {r['preset']} | {r['variant']} | {r['mode']} | {r['params'] / 1e6:.2f} M | "
                     f"{r['median_ms']:.2f} | {_opt(r.get('p90_ms'))} | {_tail(r)} | {r['min_ms']:.2f} | "
                     f"{r['calls_per_s']:.1f} | {speed} | {'yes' if r['realtime_chunked'] else 'no'} | "
                     f"{'yes' if r['realtime_every_step'] else 'no'} | {r['max_rate_every_step_hz']:.1f} | "
                     + (f"{r['floor_ms']:.2f} ({r['bound']}) | {r['x_floor']:.2f}x |" if r.get("floor_ms") else
                        "- | - |"))
    return "\n".join(lines)


def run_latency_benchmark(policies: list[str] | None = None, presets: list[str] | None = None,
                          modes: list[str] | None = None, steps: list[int] | None = None,
                          samplers: list[str] | None = None, device: str = "auto", threads: int | None = None,
                          rate_hz: float | None = None, out: str | None = None, quick_timing: bool = False,
                          policy_args: dict[str, Any] | None = None,
                          runners: dict[str, PolicyRunner] | None = None, task: str | None = None) -> dict[str, Any]:
    """Time every named policy at batch 1: a registered one at each preset, mode and sampler setting; an outside
    one (module:factory or a plug-in, built with `policy_args`) as it is; `runners` (`latency --checkpoint`: a
    trained run or published model, already loaded and configured) in each of `modes` (default: the exact modes and
    auto), in place of the untrained registry policies unless `policies` names some. `task`: the untrained
    networks' shapes (default Push-T; the baselines are Push-T's only, left out for another task)."""
    if threads:
        torch.set_num_threads(threads)
    dev = pick_device(device)
    own = {task_of(r).name for r in (runners or {}).values()}
    if len(own) > 1 or (task is not None and own and own != {get_task(task).name}):
        raise BCBenchError(f"--checkpoint runs of {', '.join(sorted(own))} timed as {task or 'one table'}: time one "
                           "task's runs at a time, on their own task (leave --task out)")
    task = task or next(iter(own), None)  # a trained run's own task
    the_task = get_task(task)
    rate_hz = rate_hz or the_task.control_hz
    names = policies or [n for n in REGISTRY if the_task.name == "pusht" or is_learned(n)]
    outside = {n: outside_policy(n, policy_args) for n in names if n not in REGISTRY}  # checked before timing
    if any(not 1 <= k <= 100 for k in steps or []):
        raise BCBenchError("--steps must be in 1..100")
    timing = TimingConfig(min_calls=5, min_seconds=0.5, max_seconds=20) if quick_timing else TimingConfig()
    jobs = [(n, p) for n in names for p in (presets or ["paper", "quick"])] if policies or not runners else []
    rows: list[dict[str, Any]] = []
    for path, runner in (runners or {}).items():
        rows += _checkpoint_rows(path, runner, modes or [*EXACT_MODES, AUTO], dev, timing, rate_hz)
    for name, policy in outside.items():
        rows.append({"policy": policy.name, "preset": "-", "mode": "as given", "variant": "default",
                     "params": int(policy.describe().get("parameters", 0)), "source": name,
                     **measure_runner(policy, timing, rate_hz)})
    for name, preset in tqdm(jobs, desc="latency", unit="policy"):
        if name in outside or any(r["policy"] == name and r["preset"] == "-" for r in rows):
            continue  # baselines have no sizes
        rows += _rows_for(name, preset, modes or [*MODES, AUTO], samplers or ["ddpm", "ddim"],
                          list(steps or DEFAULT_STEPS), dev, timing, rate_hz, the_task)
    best = against_floor(rows)  # every row against the best limits this run measured
    out_dir = Path(out) if out else Path("runs") / f"latency-{datetime.now():%Y%m%d-%H%M%S}"
    record = {"type": "latency-benchmark", "task": the_task.name, "device": str(dev), "rate_hz": rate_hz,
              "timing": timing.__dict__,
              "machine_limits": best, "floor_rule": f"{floor_ms.__doc__} The limits: the best of those measured "
              "right before each row (bcbench.evaluation.floor).",
              "rows": rows, "verdict_rule": verdicts.__doc__, **provenance(str(dev))}
    write_json(out_dir / "latency.json", record)
    table = _table(rows, rate_hz)
    with atomic_path(out_dir / "latency.md") as tmp:
        tmp.write_text(table + "\n")
    print(table)
    return {"json": str(out_dir / "latency.json"), "table": str(out_dir / "latency.md"), "record": record}
