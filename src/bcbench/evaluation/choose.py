"""`bcbench choose`, the part that runs policies: times each one at batch 1 in every exact mode in interleaved
rounds, re-scores a few test episodes live, and records a rollout of the chosen one. The reading and the choice
are bcbench.analysis.choose's (files only); the command line wires the two (bcbench.cli.main.cmd_choose).

Timing follows `--backend auto`'s trial (bcbench.evaluation.auto), widened to every policy: each policy's exact
modes (torch fast, OpenVINO fp32, ONNX Runtime fp32; reference, the paper's unsplit form, is slower by design and
auto never picks it) are set up once, then every (policy, mode) is called in turn in each round, warmed after each
switch, so a drifting shared machine treats them all alike; the lowest median per policy is what auto would pick.
A policy from outside bcbench runs as given (one mode). Each call's floor (weights read and FLOPs against this
machine's measured limits, bcbench.evaluation.floor) is computed for the fastest mode of a trained policy.

Re-scoring runs the committed evaluation's own setting (sampler, steps, torch fast, the policy's seed 0, the same
test seeds), so a deterministic policy's episodes match the committed ones up to floating point, and a stochastic
one's too: each episode draws its noise from a stream seeded by its episode seed (bcbench.evaluation.controller).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from bcbench.errors import BCBenchError
from bcbench.evaluation.auto import CANDIDATES, WARM, mode_state, restore_state
from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.config import EvalConfig, StrategyConfig
from bcbench.evaluation.evaluate import evaluate
from bcbench.evaluation.floor import best_limits, call_work, floor_ms, machine_limits
from bcbench.evaluation.timing import self_clock, summarize_ms
from bcbench.interface import ChunkPolicy, example_observation
from bcbench.policies.learned import PolicyRunner
from bcbench.protocol import CONTROL_DT_S, TEST_SEED_START
from bcbench.utils.system import CpuContention

ROUNDS = 10


@dataclass
class ChooseConfig:
    """What `bcbench choose` runs on this machine."""

    episodes: int = 5
    """test episodes re-scored live per policy (paired with the committed scores of the same seeds)"""
    calls: int = 100
    """timed calls per policy and mode at least (100 give a p99; fewer report the maximum, labelled)"""
    rate_hz: float = 10.0
    """the control loop's rate: a call of L seconds then takes d = ceil(L x rate) steps"""
    rounds: int = ROUNDS
    """interleaved timing rounds (each calls every policy and mode in turn)"""
    threads: int | None = None
    """torch threads (default: torch's choice, one per core)"""
    video: bool = True
    """record one rollout of the chosen policy"""

    def __post_init__(self) -> None:
        if self.episodes < 1 or self.calls < 1 or self.rounds < 1:
            raise BCBenchError(f"--episodes and --calls must be >= 1, got {self.episodes}, {self.calls}")
        if not (self.rate_hz > 0 and math.isfinite(self.rate_hz)):
            raise BCBenchError(f"--rate must be a control rate in Hz above 0, got {self.rate_hz:g}")
        if self.threads is not None and self.threads < 1:
            raise BCBenchError(f"--threads must be >= 1, got {self.threads}")

    @property
    def per_round(self) -> int:
        return max(1, -(-self.calls // min(self.rounds, self.calls)))


def _setups(policy: ChunkPolicy) -> tuple[dict[str, Any], dict[str, str]]:
    """Each exact mode's prepared state of a trained policy (exported and compiled once), and why a mode is
    unavailable here (e.g. no OpenVINO); an outside policy: one setup, as given."""
    if not isinstance(policy, PolicyRunner):
        return {"as given": None}, {}
    states, missing = {}, {}
    for mode in CANDIDATES:
        try:
            apply_mode(policy, mode)
        except BCBenchError as e:
            missing[mode] = str(e)
            continue
        states[mode] = mode_state(policy)
    apply_mode(policy, "fast")
    return states, missing


def time_policies(policies: dict[str, ChunkPolicy], cfg: ChooseConfig, progress: bool = True
                  ) -> dict[str, dict[str, Any]]:
    """label -> {"modes": {mode: statistics}, "fastest": ..., "floor": ..., "unavailable": {mode: why}}: every
    (policy, mode) timed in `cfg.rounds` interleaved rounds of `cfg.per_round` calls after WARM calls each."""
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    setups = {label: _setups(p) for label, p in policies.items()}
    slots = [(label, mode) for label, (states, _) in setups.items() for mode in states]
    samples: dict[tuple[str, str], list[float]] = {s: [] for s in slots}
    limits = [machine_limits()]  # this machine's limits, before and after the rounds: the floor takes the best
    obs = {label: example_observation(1, p.obs_horizon) for label, p in policies.items()}
    rounds = min(cfg.rounds, cfg.calls)
    with CpuContention() as contention:
        for r in range(rounds):
            for label, mode in slots[r % len(slots):] + slots[:r % len(slots)]:
                policy, state = policies[label], setups[label][0][mode]
                if state is not None:
                    restore_state(policy, state)
                samples[(label, mode)] += _timed(policy, obs[label], cfg.per_round)
            if progress:
                print(f"  timing round {r + 1}/{rounds}", flush=True)
    contention.warn("the policies for `bcbench choose`")
    limits.append(machine_limits())
    best = best_limits(limits)
    out = {}
    for label, (states, missing) in setups.items():
        modes = {m: {k: v for k, v in summarize_ms(_ms(samples[(label, m)])).items() if k != "samples_ms"}
                 for m in states}
        fastest = min(modes, key=lambda m: modes[m]["median_ms"])
        out[label] = {"modes": modes, "unavailable": missing, "fastest": {"mode": fastest, **modes[fastest]},
                      "floor": _floor(policies[label], states.get(fastest), modes[fastest]["median_ms"], best)}
    for p in policies.values():  # back to torch fast: what the committed scores ran
        if isinstance(p, PolicyRunner):
            apply_mode(p, "fast")
    return {"policies": out, "machine_limits": best, "cpu_contention": contention.result, "rounds": rounds,
            "calls_per_round": cfg.per_round, "warm_calls": WARM, "threads": torch.get_num_threads()}


def _ms(values: list[float]) -> Any:
    import numpy as np

    return np.array(values) * 1e3


def _timed(policy: ChunkPolicy, obs: dict[str, Any], n: int) -> list[float]:
    """`n` timed calls after WARM untimed ones (what a switch leaves cold), in seconds; a policy that times itself
    (a LeRobot sidecar) reports its own compute time."""
    import time

    clock = self_clock(policy)
    for _ in range(WARM):
        policy.predict_action_chunk(obs)
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        policy.predict_action_chunk(obs)
        out.append(clock() if clock is not None else time.perf_counter() - t0)
    return out


def _floor(policy: ChunkPolicy, state: Any, median_ms: float, limits: dict[str, float]) -> dict[str, Any] | None:
    """The floor of a trained policy's call here and its fastest median's ratio to it (None for outside ones)."""
    if not isinstance(policy, PolicyRunner) or state is None:
        return None
    apply_mode(policy, "fast")  # the work is counted on the torch graph, which every exported form runs
    work = call_work(policy)
    f = floor_ms(work, limits)
    return {**work, **f, "x_floor": median_ms / f["floor_ms"] if f["floor_ms"] > 0 else None}


def rescore(policy: ChunkPolicy, episodes: int, seed_start: int = TEST_SEED_START, max_steps: int = 300,
            progress: bool = True) -> dict[str, Any]:
    """`episodes` test episodes from `seed_start`, in the policy's current mode: seeds, scores and the estimate."""
    result = evaluate(policy, EvalConfig(episodes=episodes, seed_start=seed_start, max_steps=max_steps), None,
                      progress=progress)
    return {"seeds": [e["seed"] for e in result["episodes"]], "scores": [e["score"] for e in result["episodes"]],
            "episodes": episodes, "mean_score": result["summary"]["mean_score"],
            "mode": getattr(getattr(policy, "info", None), "mode", None) or "as given",
            "wall_time_s": result["summary"]["wall_time_s"]}


def rollout_video(policy: ChunkPolicy, out: Path, d: int, strategy: str = "naive", horizon: int | None = None,
                  seed_start: int = TEST_SEED_START) -> str | None:
    """One episode of the chosen policy run as recommended: async at a fixed delay of d control steps, with the
    strategy and execution horizon, its video in out/videos/; the video's path."""
    cfg = EvalConfig(episodes=1, seed_start=seed_start, video=1, execution="async",
                     latency_ms=d * CONTROL_DT_S * 1e3, execution_horizon=horizon,
                     strategy=StrategyConfig(strategy, rtc_jacobian=False))
    result = evaluate(policy, cfg, out, progress=False)
    return result["episodes"][0]["video"]
