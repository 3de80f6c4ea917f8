""""Which policy for my control loop": one row per policy, the first table of a report.

Per policy (a run of the study): its setting (the one the study swept in real time, fixed in the study file,
else its preset's default: never the best score on the evaluation episodes, which would be a selection on
them), its score with the 95% interval, its median call at batch 1 in the fastest exact mode timed on this
machine (from one interleaved run of every policy and mode where the folder has one: `one_interleaved_run`),
and the highest control rate at which it keeps its sync score under real-time execution (from the delay sweep
and that call time; see bcbench.analysis.realtime.highest_safe_rate). Reads rows and sweep records only.
"""

from __future__ import annotations

from typing import Any

from bcbench.analysis.fewstep import interleaved_medians, one_interleaved_run
from bcbench.analysis.realtime import highest_safe_rate, largest_safe_delay
from bcbench.analysis.results import Row
from bcbench.modes import EXACT_MODES
from bcbench.stats import fmt_estimate

HEADER = ["policy", "setting", "score [95% CI]", "median ms, batch 1 (fastest exact mode)",
          "highest control rate keeping its score"]


def fastest_exact(row: Row, interleaved: dict[str, dict[str, Any]] | None = None) -> tuple[str, float] | None:
    """(mode, median ms) of the fastest exact mode this row was timed in: in `interleaved` (one_interleaved_run)
    where that run timed its setting, else in the row's own timing record (mode "openvino-fp32, interleaved"
    names the source)."""
    timed = [(f"{m}, interleaved", ms) for m, ms in interleaved_medians(interleaved, row.policy, row.variant).items()]
    timed = timed or [(m, float(row.latency[m]["median_ms"])) for m in EXACT_MODES if m in row.latency]
    return min(timed, key=lambda t: t[1]) if timed else None


def _sweep_of(run_label: str, realtime: dict[str, dict[str, Any]]) -> tuple[str, dict[str, Any]] | None:
    """The torch sweep of a run: its label, or its label with the swept sampler ("... DDIM10")."""
    for label, settings in realtime.items():
        if "[" not in label and (label == run_label or label.rsplit(" ", 1)[0] == run_label):
            return label, settings
    return None


def _setting_row(rows: list[Row], sweep_label: str | None, run_label: str) -> Row:
    if sweep_label and sweep_label != run_label:  # the sweep names its sampler setting: "... DDIM10"
        variant = sweep_label.rsplit(" ", 1)[1].lower()
        for r in rows:
            if r.variant == variant:
                return r
    # no sweep: the preset's own setting, or for a sampler sweep its 10-step DDIM/Euler (the study's few-step
    # setting), fixed by this rule rather than by the scores
    for variant in ("default", "ddim10", "euler10"):
        for r in rows:
            if r.variant == variant:
                return r
    return rows[0]


def chosen_settings(rows: list[Row], realtime: dict[str, dict[str, Any]]) -> dict[str, Row]:
    """Each run's one setting, by run label in the rows' order: the one its real-time sweep names, else its preset's
    default (or DDIM-10 / Euler-10 for a sampler sweep). Fixed by the study file, never by the scores, so a
    comparison made on it (this table, bcbench.analysis.baseline) selects nothing on the evaluation episodes."""
    runs: dict[str, list[Row]] = {}
    for r in rows:
        runs.setdefault(r.run_label or r.label, []).append(r)
    out = {}
    for run_label, group in runs.items():
        sweep = _sweep_of(run_label, realtime)
        out[run_label] = _setting_row(group, sweep[0] if sweep else None, run_label)
    return out


def _rate_cell(settings: dict[str, Any] | None, ms: float | None, margin: float) -> str:
    if settings is None or ms is None:
        return "not swept"
    safe = {e: largest_safe_delay(settings, e, margin) for e in ("async", "blocking")
            if any(k.startswith(f"realtime-{e}-d") for k in settings)}
    if not safe:
        return "not swept"
    mode, d = max(safe.items(), key=lambda kv: kv[1] or 0)
    if not d:
        return "none shown: no delay swept is shown within the margin of sync"
    rate = highest_safe_rate(d, ms) or 0.0
    return (f"{rate:.1f}" if rate < 100 else f"{rate:.0f}") + f" Hz ({mode}, up to d = {d})"


def control_loop_rows(rows: list[Row], realtime: dict[str, dict[str, Any]], margin: float,
                      paired: dict[str, dict[str, Any]] | None = None) -> list[list[str]]:
    """The table's rows, in the report's row order (one per run); `paired`: the folder's interleaved timings by
    mode (bcbench.analysis.fewstep.load_paired)."""
    interleaved = one_interleaved_run(paired or {})
    out = []
    for run_label, row in chosen_settings(rows, realtime).items():
        sweep = _sweep_of(run_label, realtime)
        fast = fastest_exact(row, interleaved)
        setting = row.variant.upper() if row.variant != "default" else (row.preset or "-")
        out.append([run_label, setting, fmt_estimate(row.summary["mean_score"]),
                    f"{fast[1]:.1f} ({fast[0]})" if fast else "-",
                    _rate_cell(sweep[1] if sweep else None, fast[1] if fast else None, margin)])
    return out


def control_loop_lines(rows: list[Row], realtime: dict[str, dict[str, Any]], margin: float,
                       paired: dict[str, dict[str, Any]] | None = None) -> list[str]:
    table = control_loop_rows(rows, realtime, margin, paired)
    run = one_interleaved_run(paired or {})
    source = (f" Times marked 'interleaved' come from one run that timed every policy and mode in turn, "
              f"{next(iter(run.values()))['rounds']} rounds (latency-paired*.json), so that neither a drifting "
              "machine nor the hours between a study's stages favour one of them; the others from each run's own "
              "timing stage." if run else "")
    return ["## Which policy for my control loop", "",
            "One row per policy: its setting (the one swept in real time, fixed in the study file; else its preset's "
            "default, or DDIM-10 / Euler-10 for a sampler sweep), its score, its median call at batch 1 in the "
            "fastest exact mode timed on this machine, and "
            f"the highest control rate at which its score stays within {margin} of sync under real-time execution "
            "(the larger safe delay of async and blocking, divided by that call time). The machine is named once, "
            "at the top; each run's training under 'Training: converged?'." + source, "",
            "| " + " | ".join(HEADER) + " |", "|---" * len(HEADER) + "|",
            *("| " + " | ".join(r) + " |" for r in table), ""]
