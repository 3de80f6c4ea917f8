"""The report's real-time section (`## Under real-time execution`): per swept policy the score at sync, at each
delay, at measured latency and under hardware profiles, and the largest safe delay and control rate. Reads result
files' records only, as `bcbench.analysis.report` does, which places it.
"""

from __future__ import annotations

from typing import Any

from bcbench.analysis.provenance import sweep_provenance
from bcbench.analysis.realtime import margin_power_sentence, naive_sweep_of, pooled_sentence, safe_delay_sentence
from bcbench.analysis.results import Row
from bcbench.stats import fmt_estimate

REALTIME_COLUMNS = ("sync", *(f"{e}-d{d}" for e in ("async", "blocking") for d in (1, 2, 4, 8)),
                    "async-measured", "blocking-measured", "async-a100")


def same_as_fixed(settings: dict[str, Any], name: str) -> str | None:
    """The fixed-delay setting a measured or profile setting repeats, if every one of its calls had the same d
    (e.g. a call under 100 ms is d = 1 at 10 Hz): then its episodes are that setting's, not separate evidence."""
    if name.rsplit("-", 1)[-1].startswith("d") or name == "realtime-sync":
        return None
    steps = settings[name]["summary"].get("delay_steps") or {}
    mode = name.removeprefix("realtime-").split("-")[0]
    if len(steps) == 1 and f"realtime-{mode}-d{next(iter(steps))}" in settings:
        return f"{mode}-d{next(iter(steps))}"
    return None


def realtime_table(realtime: dict[str, dict[str, Any]]) -> list[str]:
    """Mean score per policy (rows) and setting (columns); measured settings with their median call; a setting
    that repeats a fixed-delay one is marked '= thatsetting'."""
    def cell(settings: dict[str, Any], col: str) -> str:
        r = settings.get(f"realtime-{col}")
        if r is None:
            return "-"
        ms = r["summary"].get("latency_source", {}).get("median_ms") if col.endswith("measured") else None
        same = same_as_fixed(settings, f"realtime-{col}")
        return (f"{r['summary']['mean_score']['value']:.3f}" + (f" ({ms:.0f} ms)" if ms is not None else "")
                + (f" = {same}" if same else ""))

    head = "| policy | " + " | ".join(REALTIME_COLUMNS) + " |"
    rows = [f"| {label} | " + " | ".join(cell(settings, c) for c in REALTIME_COLUMNS) + " |"
            for label, settings in realtime.items()]
    return [head, "|---" * (len(REALTIME_COLUMNS) + 1) + "|", *rows]


def realtime_lines(realtime: dict[str, dict[str, Any]], margin: float, rows: list[Row] | None = None) -> list[str]:
    """Per swept policy: sync, each delay, measured and profile scores, the largest safe delay and rate; `rows` (one
    per run): what the sweeps ran on where it differs from them (`provenance.sweep_provenance`)."""
    if not realtime:
        return []
    intro = (f"Largest safe delay, per execution mode: the largest d up to which every score stays within the margin "
             f"({margin}) of the sync score (paired interval of the difference above -margin); at 10 Hz, d steps "
             "allow a call of up to d x 100 ms. Highest safe control rate, in the mode with the larger safe delay: "
             "the fastest rate at which the policy's measured call "
             "(median; slowest timed call) still takes at most that many steps (d / L), reading the delay curve "
             "as holding in steps at other rates.")
    out = ["## Under real-time execution (10 Hz control)", "",
           " ".join(filter(None, [intro, pooled_sentence(realtime), sweep_provenance(realtime, rows or []),
                                 margin_power_sentence(realtime, margin)])), ""]
    out += [*realtime_table(realtime), "", "Every setting with its 95% interval, and what the sweep says (a measured "
            "or profile setting whose calls all took the same d repeats that fixed-delay setting and is marked so):",
            ""]
    for label, settings in realtime.items():
        parts = [f"{name.removeprefix('realtime-')} " + (f"= {same} (every call d = {same.rsplit('-d', 1)[1]}: the "
                 "same episodes, not separate evidence)" if (same := same_as_fixed(settings, name))
                 else fmt_estimate(r["summary"]["mean_score"])) for name, r in settings.items()]
        out.append(f"- {label}: " + "; ".join(parts) + ". "
                   + safe_delay_sentence(settings, margin, naive_sweep_of(realtime, label)))
    return [*out, ""]
