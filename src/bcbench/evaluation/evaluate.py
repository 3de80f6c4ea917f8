"""Closed-loop evaluation on a task: seeded episodes, parallel simulators, batched policy calls.

Protocol (Diffusion Policy's, which the study follows): episode i starts from the task's seeded start for seed
100000 + i; at most the task's cap of steps; the score of an episode is its maximum reward, success ends it
(Push-T: reward min(coverage / 0.95, 1), success coverage > 0.95, 300 steps; each task states its own).

Simulators run in worker processes (one per core by default); the policy runs in this process and is
called once per re-planning round for every episode that needs a new chunk, so a batch of B episodes
costs one forward pass. Latency at batch 1 is the business of `bcbench latency`, not of this module.
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from bcbench.data.rollouts import Recorder
from bcbench.errors import BCBenchError
from bcbench.evaluation.config import EvalConfig
from bcbench.evaluation.controller import ChunkedController
from bcbench.evaluation.latency_sources import LatencySource
from bcbench.evaluation.strategies import Strategy
from bcbench.interface import ChunkPolicy, CorrectionHead
from bcbench.stats import score_summary
from bcbench.tasks import Task, declared_task, get_task
from bcbench.tasks.workers import WorkerPool
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance


@dataclass
class EpisodeResult:
    episode: int
    seed: int
    score: float = 0.0
    final_coverage: float = 0.0
    max_coverage: float = 0.0
    success: bool = False
    length: int = 0
    initial_state: list[float] = field(default_factory=list)
    final_state: list[float] = field(default_factory=list)  # agent x, y, block x, y, angle at the end
    video: str | None = None




def episode_task(policy: ChunkPolicy, name: str) -> Task:
    """The task `name`, checked against the one the policy was trained on (a trained runner's, or an outside
    policy's `task` attribute where it has one): one line when they differ."""
    task = get_task(name)
    own = declared_task(policy)
    if own is not None and own != task.name:
        raise BCBenchError(f"{getattr(policy, 'name', 'the policy')} was trained on {own}, not {task.name}: "
                           f"pass --task {own} (or leave --task out)")
    return task


def _split(items: dict[int, Any] | list[Any], n: int, key=lambda x: x) -> list[Any]:
    """Group by worker (episode % n); None where a worker has nothing to do."""
    groups: list[Any] = [None] * n
    if isinstance(items, dict):
        for ep, v in items.items():
            groups[ep % n] = {**(groups[ep % n] or {}), ep: v}
    else:
        for it in items:
            w = key(it) % n
            groups[w] = [*(groups[w] or []), it]
    return groups


def run_episodes(policy: ChunkPolicy, cfg: EvalConfig, out_dir: Path | None = None, progress: bool = True,
                 weak: ChunkPolicy | None = None, source: LatencySource | None = None,
                 head: CorrectionHead | None = None, recorder: Recorder | None = None
                 ) -> tuple[list[EpisodeResult], dict[str, Any]]:
    """Run cfg.episodes closed-loop episodes; returns per-episode results and timing counters. `weak`: BID's
    weaker policy (cfg.strategy.bid_weak, loaded by the caller); `source`: cfg's latency source, already resolved
    (a sweep that looked at its delays first: measured calls are then not timed twice); `head`: the correction
    head of --strategy correction (cfg.strategy.correction, loaded by the caller); `recorder`: collects every
    step's observation and executed action (`bcbench eval --record`)."""
    task = episode_task(policy, cfg.task)
    n_workers = max(1, min(cfg.workers or os.cpu_count() or 1, cfg.episodes))
    results = {i: EpisodeResult(episode=i, seed=cfg.seed_start + i) for i in range(cfg.episodes)}
    source = source or LatencySource.parse(cfg.latency, cfg.latency_ms)
    source.rate_hz = task.delay_rate  # a latency counts in this task's control steps
    strategy = Strategy(cfg.strategy, policy, weak, head)  # checked before any simulator starts
    source.resolve(policy, strategy)  # measured: timed now, before any simulator runs beside it
    controller = ChunkedController(policy, cfg.action_horizon, cfg.execution,
                                   source.delay_fn({i: r.seed for i, r in results.items()}), cfg.execution_horizon,
                                   strategy, task)
    video_dir = (out_dir / "videos") if out_dir is not None else Path("videos")
    pool = WorkerPool(n_workers, cfg.video_size, task.name)
    policy_time, env_steps, t0 = 0.0, 0, time.perf_counter()
    try:
        resets = [(i, r.seed, str(video_dir / f"episode_{i:03d}_seed_{r.seed}.mp4") if i < cfg.video else None)
                  for i, r in results.items()]
        for ep, (obs, coverage, state) in pool.call("reset", _split(resets, n_workers, key=lambda x: x[0])).items():
            controller.reset(ep, obs, seed=results[ep].seed)
            if recorder is not None:
                recorder.reset(ep, results[ep].seed, obs)
            results[ep].initial_state = state
            results[ep].final_coverage = results[ep].max_coverage = coverage
        active = sorted(results)
        bar = tqdm(total=cfg.max_steps, desc=f"eval {getattr(policy, 'name', '')}".strip(), unit="step",
                   disable=not progress)
        for _ in range(cfg.max_steps):
            if not active:
                break
            tp = time.perf_counter()
            actions = controller.act(active)
            policy_time += time.perf_counter() - tp
            for ep in active if recorder is not None else ():
                recorder.acted(ep, actions[ep])
            payload = {ep: (actions[ep], results[ep].score) for ep in active}
            stepped = pool.call("step", _split(payload, n_workers))
            finished = []
            for ep, (obs, reward, terminated, coverage, state) in stepped.items():
                r = results[ep]
                r.final_state = state
                r.length += 1
                r.score = max(r.score, reward)
                r.final_coverage, r.max_coverage = coverage, max(r.max_coverage, coverage)
                r.success = r.success or terminated
                env_steps += 1
                if terminated:
                    finished.append(ep)
                else:
                    controller.observe(ep, obs)
                    if recorder is not None:
                        recorder.observed(ep, obs)
            for ep in finished:
                controller.drop(ep)
            active = [ep for ep in active if ep not in finished]
            bar.update()
            bar.set_postfix(running=len(active), mean_score=f"{np.mean([r.score for r in results.values()]):.3f}")
        bar.close()
        paths = pool.call("close", _split(list(results), n_workers))
        for ep, path in paths.items():
            results[ep].video = path
    finally:
        pool.stop()
    wall = time.perf_counter() - t0
    timing = {
        "wall_time_s": wall, "env_steps": env_steps, "env_steps_per_s": env_steps / wall if wall > 0 else 0.0,
        "policy_calls": controller.n_calls, "chunks_planned": controller.n_plans, "policy_time_s": policy_time,
        "workers": n_workers, "execution": cfg.execution, "latency_source": source.describe(),
        "strategy": strategy.describe(),
        "delay_steps": {str(d): int(n) for d, n in zip(*np.unique(controller.delays, return_counts=True),
                                                          strict=True)},
    }
    return [results[i] for i in sorted(results)], timing


def evaluate(policy: ChunkPolicy, cfg: EvalConfig, out_dir: str | Path | None = None, progress: bool = True,
             extra: dict[str, Any] | None = None, weak: ChunkPolicy | None = None,
             source: LatencySource | None = None, head: CorrectionHead | None = None,
             record: str | Path | None = None) -> dict[str, Any]:
    """Evaluate and (if out_dir) write `eval.json` there atomically; returns the result dict (`weak`, `source`,
    `head`: as for run_episodes). `record`: also write the episodes' observations and executed actions to this
    rollout store (bcbench.data.rollouts), stamped with the policy, its weights and the evaluation's settings."""
    out = Path(out_dir) if out_dir is not None else None
    recorder = Recorder() if record is not None else None
    episodes, timing = run_episodes(policy, cfg, out, progress, weak, source, head, recorder)
    if recorder is not None:
        recorder.write(record, {"task": cfg.task, "policy": policy.describe(), "eval_config": asdict(cfg),
                                **provenance(str(getattr(policy, "device", "cpu")))})
    summary = score_summary(
        np.array([e.score for e in episodes]), np.array([e.success for e in episodes]),
        np.array([e.final_coverage for e in episodes]),
    )
    summary.update(timing)
    summary["mean_length"] = float(np.mean([e.length for e in episodes]))
    describe = policy.describe()
    summary["parameters"] = describe.get("parameters", 0)
    result = {
        "type": "evaluation",
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "policy": describe,
        "task": get_task(cfg.task).describe(),  # checked against the policy's by run_episodes
        "eval_config": asdict(cfg),
        "summary": summary,
        "episodes": [asdict(e) for e in episodes],
        **provenance(str(getattr(policy, "device", "cpu"))),
        **(extra or {}),
    }
    if out is not None:
        write_json(out / "eval.json", result)
    return result
