"""Which timing sitting a latency record belongs to.

A sitting is a span of minutes in which a study's latency stages ran (bcbench.analysis.compute.timing_sittings, from
the study's index). Timings compare only within one: a VM's speed drifts between sittings (a 2-core AMD EPYC Zen 3
measured its GEMM rate at 175-184 GFLOP/s in one sitting and at 97-121 a day later, flags avx2), so a ratio of two
latencies from different sittings measures the machine as much as the networks.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

Sitting = tuple[datetime, datetime]  # (start, end), UTC

# a latency record's `created` is its stage's start; the index's start (finished - seconds) can be later where the
# driver received the result late (Ray): sittings are at least 30 min apart, so a minute's slack costs nothing
SLACK = timedelta(seconds=60)


def sitting_of(timed_at: str, sittings: list[Sitting]) -> int | None:
    """The index of the sitting whose span holds the ISO time `timed_at` (a latency record's `created`); None where
    either is unknown or no sitting holds it (a latency file without its index line: then compared as before)."""
    if not timed_at or not sittings:
        return None
    t = datetime.fromisoformat(timed_at)
    t = t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)
    return next((i for i, (a, b) in enumerate(sittings) if a - SLACK <= t <= b + SLACK), None)
