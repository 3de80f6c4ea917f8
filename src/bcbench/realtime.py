"""Latency sources for real-time evaluation: how many control steps a policy call takes.

The control loop runs at 10 Hz (0.1 s per environment step), so a call that takes L seconds takes
d = ceil(L / 0.1) steps (`steps_for`). L comes from one of:
- a fixed number of milliseconds (`--latency-ms 250`, d = 3);
- `measured`: the policy's own call times on this machine, timed before the episodes with the backend in
  use, one drawn per call (each episode draws from its own stream, seeded by its seed);
- `profile:NAME`: a named hardware profile; `a100` holds the study's A100 inference times.
How the world moves meanwhile (sync, blocking, async) is the controller's business
(`bcbench.env.controller`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bcbench.errors import BCBenchError

CONTROL_DT_S = 0.1  # Push-T's control period (10 Hz)

# The study's A100 inference times (ms) per call. Diffusion Policy (and flow matching, the same network) at
# K steps: the encoder-and-overhead share plus K U-Net calls, from its two measured points (K = 10, 100).
_A100_DP_PER_STEP_MS = (1109.4 - 116.5) / 90
_A100_DP_BASE_MS = 116.5 - 10 * _A100_DP_PER_STEP_MS
PROFILES: dict[str, dict[str, float]] = {"a100": {"cnn_mlp": 2.2, "resnet50": 13.0, "bct": 12.0}}


def steps_for(latency_s: float) -> int:
    """Control steps a call of `latency_s` seconds takes: ceil(L / 0.1), 0 for no latency."""
    if latency_s < 0:
        raise BCBenchError(f"latency must be >= 0, got {latency_s * 1e3:g} ms")
    return max(0, math.ceil(latency_s / CONTROL_DT_S - 1e-9))


def profile_ms(profile: str, policy: str, steps: int | None = None) -> float:
    """A hardware profile's time for one call of `policy` (generative policies: at `steps` steps)."""
    if profile not in PROFILES:
        raise BCBenchError(f"unknown latency profile '{profile}' (known: {', '.join(sorted(PROFILES))})")
    if profile == "a100" and policy in ("diffusion", "flow") and steps:
        return _A100_DP_BASE_MS + steps * _A100_DP_PER_STEP_MS
    if policy not in PROFILES[profile]:
        raise BCBenchError(f"the '{profile}' profile has no inference time for '{policy}'")
    return PROFILES[profile][policy]


@dataclass
class LatencySource:
    """Where d comes from: `fixed` (ms), `measured` (call times in ms), or `profile` (a name)."""

    kind: str = "none"
    ms: float = 0.0
    samples_ms: list[float] = field(default_factory=list)
    name: str = ""

    @classmethod
    def parse(cls, latency: str | None, latency_ms: float | None) -> LatencySource:
        if latency_ms is not None and latency is not None:
            raise BCBenchError("give --latency-ms or --latency, not both")
        if latency_ms is not None:
            if latency_ms < 0:
                raise BCBenchError(f"--latency-ms must be >= 0, got {latency_ms:g}")
            return cls("fixed", ms=float(latency_ms))
        if latency is None:
            return cls()
        if latency == "measured":
            return cls("measured")
        if latency.startswith("profile:"):
            name = latency.split(":", 1)[1]
            if name not in PROFILES:
                raise BCBenchError(f"unknown latency profile '{name}' (known: {', '.join(sorted(PROFILES))})")
            return cls("profile", name=name)
        raise BCBenchError(f"--latency must be 'measured' or 'profile:NAME', got '{latency}'")

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind}
        if self.kind == "fixed":
            out["ms"] = self.ms
        if self.kind == "profile":
            out.update(name=self.name, ms=self.ms)
        if self.kind == "measured":
            ms = np.array(self.samples_ms)
            out.update(calls=int(ms.size), median_ms=float(np.median(ms)), max_ms=float(ms.max()))
        return out

    def resolve(self, runner: Any) -> None:
        """Fill in what depends on the policy: its profile time, or its measured call times on this machine."""
        if self.kind == "profile":
            self.ms = profile_ms(self.name, runner.name, getattr(runner, "extra", {}).get("steps"))
        elif self.kind == "measured" and not self.samples_ms:
            from bcbench.latency import TimingConfig, random_observation, time_calls

            obs = random_observation(1, runner.obs_horizon)
            self.samples_ms = time_calls(lambda: runner.predict_action_chunk(obs), TimingConfig())["samples_ms"]

    def delay_fn(self, seeds: dict[int, int]) -> Callable[[int], int]:
        """env id -> d for its next call; measured draws come from each episode's own stream."""
        if self.kind in ("fixed", "profile"):
            d = steps_for(self.ms / 1e3)
            return lambda env_id: d
        if self.kind == "measured":
            steps = np.array([steps_for(ms / 1e3) for ms in self.samples_ms])
            rngs = {i: np.random.default_rng([7, s]) for i, s in seeds.items()}
            return lambda env_id: int(rngs[env_id].choice(steps))
        return lambda env_id: 0


def sweep_settings(delays: list[int], executions: list[str], profiles: list[str], measured: bool
                   ) -> list[tuple[str, str, dict[str, Any]]]:
    """(name, execution, latency options) of every setting of a sweep; sync (d = 0) first."""
    bad = [d for d in delays if d < 0]
    if bad:
        raise BCBenchError(f"delays must be >= 0, got {bad[0]}")
    settings: list[tuple[str, str, dict[str, Any]]] = [("realtime-sync", "sync", {})]
    settings += [(f"realtime-{e}-d{d}", e, {"latency_ms": d * CONTROL_DT_S * 1e3})
                 for e in executions for d in sorted(set(delays)) if d > 0]
    settings += [(f"realtime-{e}-{p}", e, {"latency": f"profile:{p}"}) for e in executions for p in profiles]
    if measured:
        settings += [(f"realtime-{e}-measured", e, {"latency": "measured"}) for e in executions]
    return settings


def sweep(policy: Any, delays: list[int], executions: list[str], episodes: int, profiles: list[str],
          measured: bool, progress: bool = True, max_steps: int = 300, seed_start: int = 100_000,
          skip_missing_profiles: bool = False, done: dict[str, dict[str, Any]] | None = None,
          on_setting: Callable[[dict[str, dict[str, Any]]], None] | None = None) -> dict[str, dict[str, Any]]:
    """Score against delay d for each execution mode (sync as the d = 0 reference), plus the policy's score at
    its measured latency on this machine and under each hardware profile: evaluation results by setting.
    `done`: settings finished by an interrupted sweep (kept, not rerun); `on_setting(results so far)` is called
    after each setting, so a caller can save them (a sweep is 13 evaluations of 100 episodes in a study)."""
    from bcbench.evaluate import EvalConfig, evaluate

    usable = []
    for p in profiles:  # fail before hours of episodes, not after (or, in a study, leave that profile out)
        try:
            profile_ms(p, policy.name, getattr(policy, "extra", {}).get("steps"))
            usable.append(p)
        except BCBenchError:
            if not skip_missing_profiles:
                raise
    settings = sweep_settings(delays, executions, usable, measured)
    out = {name: r for name, r in (done or {}).items() if name in {s[0] for s in settings}}
    for name, execution, latency in settings:
        if name in out:
            continue
        cfg = EvalConfig(episodes=episodes, execution=execution, max_steps=max_steps, seed_start=seed_start,
                         **latency)
        out[name] = evaluate(policy, cfg, None, progress=progress, extra={"realtime": {"setting": name}})
        if on_setting is not None:
            on_setting(out)
    return out


def delay_vs_sync(results: dict[str, dict[str, Any]], setting: str) -> tuple[float, float, float, int]:
    """A setting's score minus sync over shared seeds, with its 95% paired-bootstrap interval and n seeds."""
    from bcbench.findings import Point, paired_interval

    def point(r: dict[str, Any]) -> Point:
        return Point("", "", "", 0.0, (0.0, 1.0), None, None, {e["seed"]: e["score"] for e in r["episodes"]})

    return paired_interval(point(results[setting]), [point(results["realtime-sync"])])


def largest_safe_delay(results: dict[str, dict[str, Any]], execution: str, margin: float) -> int | None:
    """The largest d whose score stays within the margin of sync (paired: the interval of d minus sync lies
    above -margin) for every delay up to it; None without a sync result."""
    if "realtime-sync" not in results:
        return None
    safe = 0
    delays = sorted(int(k.rsplit("-d", 1)[1]) for k in results if k.startswith(f"realtime-{execution}-d"))
    for d in delays:
        if delay_vs_sync(results, f"realtime-{execution}-d{d}")[1] <= -margin:
            break
        safe = d
    return safe


def delay_curve(results: dict[str, dict[str, Any]], execution: str) -> list[tuple[int, dict[str, Any]]]:
    """(d, mean-score estimate) of one execution mode, with sync as d = 0."""
    pts = [(0, results["realtime-sync"]["summary"]["mean_score"])] if "realtime-sync" in results else []
    prefix = f"realtime-{execution}-d"
    pts += sorted((int(k[len(prefix):]), r["summary"]["mean_score"]) for k, r in results.items()
                  if k.startswith(prefix))
    return pts


def highest_safe_rate(safe_d: int | None, latency_ms: float) -> float | None:
    """The highest control rate (Hz) at which calls of `latency_ms` stay within `safe_d` steps of delay.

    At rate f a call of L seconds takes d = ceil(L f) steps, so d <= safe_d for every f <= safe_d / L. This
    reads the score-against-delay curve, measured in 10 Hz steps, as holding in steps at other rates too
    (Diffusion Policy's Fig. 6 and Real-Time Chunking count delay in steps the same way). 0: no real-time
    rate keeps the score (even one step of delay costs more than the margin); None: no sweep to read.
    """
    if safe_d is None:
        return None
    return safe_d / (latency_ms / 1e3) if latency_ms > 0 else math.inf


def realtime_record(settings: dict[str, dict[str, Any]], study: str, label: str, variant: dict[str, Any],
                    margin: float, device: str = "cpu") -> dict[str, Any]:
    """One sweep's record, as a study's report reads it (`bcbench.results.load_realtime`): its settings'
    evaluation results under a label, with where and at which commit it ran."""
    import platform

    from bcbench.utils.system import provenance

    return {"type": "realtime", "study": {"name": study, "label": label, "variant": variant}, "margin": margin,
            "settings": settings, "node": platform.node(), **provenance(device)}
