"""The real-time sweep: score against delay d for each execution mode, plus the measured latency and the
hardware profiles; its record is what the report reads (bcbench.analysis.realtime reads it)."""

from __future__ import annotations

import copy
import json
import platform
import sys
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from bcbench.errors import BCBenchError
from bcbench.evaluation.config import StrategyConfig
from bcbench.evaluation.controller import actions_executed, async_actions_needed
from bcbench.evaluation.evaluate import EvalConfig, evaluate
from bcbench.evaluation.latency_sources import LatencySource, profile_ms, sampler_steps, steps_for
from bcbench.evaluation.strategies import Strategy
from bcbench.interface import ChunkPolicy, CorrectionHead
from bcbench.protocol import CONTROL_DT_S, SYNC_SETTING, delay_setting
from bcbench.tasks import DEFAULT_TASK, get_task, task_of
from bcbench.utils.io import read_json
from bcbench.utils.system import provenance


def sweep_settings(delays: list[int], executions: list[str], profiles: list[str], measured: bool,
                   step_s: float = CONTROL_DT_S) -> list[tuple[str, str, dict[str, Any]]]:
    """(name, execution, latency options) of every setting of a sweep; sync (d = 0) first. A delay of d steps is the
    latency d x `step_s` (the task's control step: Push-T's 0.1 s)."""
    bad = [d for d in delays if d < 0]
    if bad:
        raise BCBenchError(f"delays must be >= 0, got {bad[0]}")
    settings: list[tuple[str, str, dict[str, Any]]] = [(SYNC_SETTING, "sync", {})]
    settings += [(delay_setting(e, d), e, {"latency_ms": d * step_s * 1e3})
                 for e in executions for d in sorted(set(delays)) if d > 0]
    settings += [(f"realtime-{e}-{p}", e, {"latency": f"profile:{p}"}) for e in executions for p in profiles]
    if measured:
        settings += [(f"realtime-{e}-measured", e, {"latency": "measured"}) for e in executions]
    return settings


def sweep(policy: ChunkPolicy, delays: list[int], executions: list[str], episodes: int, profiles: list[str],
          measured: bool, progress: bool = True, max_steps: int | None = None, seed_start: int = 100_000,
          skip_missing_profiles: bool = False, done: dict[str, dict[str, Any]] | None = None,
          on_setting: Callable[[dict[str, dict[str, Any]]], None] | None = None,
          execution_horizon: int | None = None, strategy: StrategyConfig | None = None,
          weak: ChunkPolicy | None = None, measured_source: LatencySource | None = None,
          head: CorrectionHead | None = None, task: str | None = None) -> dict[str, dict[str, Any]]:
    """Score against delay d for each execution mode (sync as the d = 0 reference), plus the policy's score at
    its measured latency on this machine and under each hardware profile: evaluation results by setting.
    `done`: settings finished by an interrupted sweep (kept, not rerun); `on_setting(results so far)` is called
    after each setting, so a caller can save them (a sweep is 13 evaluations of 100 episodes in a study). A
    profile or measured setting whose every call takes the d of a fixed setting already swept reuses its episodes
    (`fixed_twin`): a fast policy's A100 and measured settings cost no episodes.
    `execution_horizon`: s of the async settings (see bcbench.evaluation.controller); `strategy` (and BID's
    `weak` policy, the correction `head`): how consecutive chunks are joined, in every setting, sync included.
    `measured_source`: the
    measured setting's calls, timed by the caller (e.g. interleaved with other strategies'); else timed here.
    `task`: the episodes' task (default: the policy's own); `max_steps` (default: its cap)."""
    task = task or task_of(policy).name
    if execution_horizon is not None:  # checked before hours of episodes
        EvalConfig(execution="async", execution_horizon=execution_horizon)
    if "async" in executions:
        check_async_delays(policy, delays, execution_horizon)
    usable = []
    for p in profiles:  # fail before hours of episodes, not after (or, in a study, leave that profile out)
        try:
            profile_ms(p, policy.name, sampler_steps(policy))
            usable.append(p)
        except BCBenchError:
            if not skip_missing_profiles:
                raise
    settings = sweep_settings(delays, executions, usable, measured, get_task(task).step_s)
    if strategy is not None and strategy.strategy == "rtc" and "async" in executions:
        note = rtc_horizon_note(policy, delays, execution_horizon)
        if note:  # allowed (the queue runs dry, the last target is held), but not RTC as its paper defines it
            print(note, file=sys.stderr)
    out = {name: r for name, r in (done or {}).items() if name in {s[0] for s in settings}}
    for name, execution, latency in settings:
        if name in out:
            continue
        cfg = EvalConfig(episodes=episodes, execution=execution, max_steps=max_steps, seed_start=seed_start, task=task,
                         execution_horizon=execution_horizon if execution == "async" else None,
                         strategy=strategy or StrategyConfig(), **latency)
        source, twin = None, None
        if "latency" in latency:  # a profile or the measured latency: its delays are known before any episode
            source = LatencySource.parse(cfg.latency, None)
            if source.kind == "measured" and measured_source is not None:
                source = copy.deepcopy(measured_source)  # timed by the caller: resolve keeps its calls
            source.rate_hz = get_task(task).delay_rate  # its calls count in this task's steps (fixed_twin reads it)
            source.resolve(policy, Strategy(cfg.strategy, policy, weak, head))
            twin = fixed_twin(source, execution, out)
        if twin is not None:
            out[name] = same_episodes(out[twin], twin, name, cfg, source)
        else:
            out[name] = evaluate(policy, cfg, None, progress=progress, extra={"realtime": {"setting": name}},
                                 weak=weak, source=source, head=head)
        if on_setting is not None:
            on_setting(out)
    return out


def finished_settings(folder: Path, policy: ChunkPolicy, episodes: int, seed_start: int, max_steps: int | None,
                      execution_horizon: int | None, strategy: StrategyConfig, task: str | None = None
                      ) -> dict[str, dict[str, Any]]:
    """The settings an interrupted sweep already wrote to `folder` (one file each, as they finish) that this sweep
    would repeat exactly: same policy (weights, checkpoint, sampler, deployment), episodes, seeds, step cap,
    strategy and async horizon. Measured settings are never kept (their times belong to the machine of the day)."""
    def plain(x: Any) -> Any:  # as a result file holds it (tuples as lists)
        return json.loads(json.dumps(x, default=str))

    task = get_task(task or task_of(policy).name)
    max_steps = max_steps or task.max_steps
    want = plain({"episodes": episodes, "seed_start": seed_start, "max_steps": max_steps, "strategy": asdict(strategy)})
    described, out = plain(policy.describe()), {}
    described.setdefault("task", task.name)  # a record from before tasks: its policy's describe() had none
    for f in sorted(folder.glob("realtime-*.json")) if folder.is_dir() else []:
        r = read_json(f)
        cfg, name = r.get("eval_config") or {}, f.stem
        if name.endswith("-measured") or {"task": DEFAULT_TASK, **(r.get("policy") or {})} != described:
            continue
        horizon = execution_horizon if cfg.get("execution") == "async" else None
        if {k: cfg.get(k) for k in want} == want and cfg.get("execution_horizon") == horizon:
            out[name] = r
    return out


def longest_horizon(policy: ChunkPolicy, d: int) -> int:
    """The most actions s a chunk holds after a delay of d (`async_actions_needed` <= pred_horizon)."""
    return policy.pred_horizon - policy.chunk_start - d


def rtc_horizon_note(policy: ChunkPolicy, delays: list[int], execution_horizon: int | None) -> str | None:
    """A note when RTC runs with fewer actions per chunk than the delay (s < d; its paper's rule is s >= d), with
    the horizons that would keep the rule, or why none can: the chunk holds d + s <= H - chunk_start actions."""
    short = [d for d in delays if actions_executed(policy.action_horizon, d, execution_horizon) < d]
    if not short:
        return None
    room = {d: longest_horizon(policy, d) for d in short}
    fits, never = [d for d in short if room[d] >= d], [d for d in short if room[d] < d]
    hints = [f"--execution-horizon s with {d} <= s <= {room[d]} keeps it at d = {d}" for d in fits]
    if never:
        hints.append(f"at d = {', '.join(map(str, never))} no horizon does (d + s <= "
                     f"{policy.pred_horizon - policy.chunk_start} with this chunk)")
    return (f"note: rtc at d = {', '.join(map(str, short))} executes fewer actions per chunk than the delay (s < d; "
            f"Real-Time Chunking needs s >= d): {'; '.join(hints)}")


def check_async_delays(policy: ChunkPolicy, delays: list[int], execution_horizon: int | None) -> None:
    """Fail before any episode when a fixed delay cannot run asynchronously with this chunk (the controller's rule,
    `async_actions_needed`, which it checks at every call), not after the settings before it ran."""
    need = {d: async_actions_needed(policy.chunk_start, d, execution_horizon) for d in sorted(set(delays)) if d > 0}
    bad = [d for d, n in need.items() if n > policy.pred_horizon]
    if bad:
        s = execution_horizon or 1  # the default horizon shrinks with d, to 1 at least
        fits = [d for d, n in need.items() if n <= policy.pred_horizon]
        raise BCBenchError(f"async d = {bad[0]} with execution horizon {s} needs {need[bad[0]]} actions of "
                           f"{policy.name}'s chunk of {policy.pred_horizon} (the current step's at index "
                           f"{policy.chunk_start}; s <= H - d): at s = {s} the delays can be {fits or 'none'}, at "
                           f"d = {bad[0]} s can be at most {max(longest_horizon(policy, bad[0]), 0)}")


def fixed_twin(source: LatencySource, execution: str, done: dict[str, dict[str, Any]]) -> str | None:
    """The fixed-delay setting already evaluated whose episodes a resolved profile or measured latency source would
    repeat: every call of it takes the same d (a profile's time, or measured calls that all round to one d), and the
    controller sees only d, so each seed's episode is the same. None where the delays vary or d was not swept."""
    ms = [source.ms] if source.kind == "profile" else source.samples_ms
    steps = {steps_for(m / 1e3, source.rate_hz) for m in ms}
    if len(steps) != 1 or (d := steps.pop()) < 1:
        return None
    name = delay_setting(execution, d)
    return name if name in done else None


def same_episodes(twin: dict[str, Any], twin_name: str, name: str, cfg: EvalConfig, source: LatencySource
                  ) -> dict[str, Any]:
    """Setting `name`'s record from its fixed-delay twin's episodes (not run again): its own configuration and
    latency source, and where its episodes come from."""
    record = copy.deepcopy(twin)
    record["eval_config"] = asdict(cfg)
    record["summary"]["latency_source"] = source.describe()
    record["realtime"] = {"setting": name, "episodes_of": twin_name}
    return record


def realtime_record(settings: dict[str, dict[str, Any]], study: str, label: str, variant: dict[str, Any],
                    margin: float, device: str = "cpu", outside_policy: str | None = None) -> dict[str, Any]:
    """One sweep's record, as a study's report reads it (`bcbench.analysis.results.load_realtime`): its settings'
    evaluation results under a label, with where and at which commit it ran."""
    where = {"outside_policy": outside_policy} if outside_policy else {}
    return {"type": "realtime", "study": {"name": study, "label": label, "variant": variant, **where}, "margin": margin,
            "settings": settings, "node": platform.node(), **provenance(device)}
