"""Reading a real-time sweep: each delay's score against sync (paired), the largest safe delay, and the
highest control rate at which a policy keeps its sync score. Reads result records only (no torch)."""

from __future__ import annotations

import math
from typing import Any

from bcbench.stats import paired_bootstrap


def seed_scores(r: dict[str, Any]) -> dict[int, float]:
    return {e["seed"]: e["score"] for e in r["episodes"]}


def delay_vs_sync(results: dict[str, dict[str, Any]], setting: str) -> tuple[float, float, float, int]:
    """A setting's score minus sync over shared seeds, with its 95% paired-bootstrap interval and n seeds."""
    return paired_bootstrap(seed_scores(results[setting]), [seed_scores(results["realtime-sync"])])


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
