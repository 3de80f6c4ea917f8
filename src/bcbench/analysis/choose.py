""""Which policy for my control loop": one row per policy, the first table of a report.

Per policy (a run of the study): its setting (the one the study swept in real time, fixed in the study file,
else its preset's default: never the best score on the evaluation episodes, which would be a selection on
them), its score with the 95% interval, its median call at batch 1 in the fastest exact mode timed on this
machine (from one interleaved run of every policy and mode where the folder has one: `one_interleaved_run`),
and the highest control rate at which it keeps its sync score under real-time execution (from the delay sweep
and that call time; see bcbench.analysis.realtime.highest_safe_rate). Reads rows and sweep records only.

The same question on the user's own machine (`bcbench choose`, `rank` and `choice` below): every published model
timed here, at the delay d = ceil(p99 latency x rate) that its slow calls imply, read from the committed sweeps of
the same weights at that d (bcbench.analysis.published); the policy with the highest committed score at its own d
is the answer. Only committed 100-episode evidence ranks: a policy scored live on a few episodes is listed, not
ranked (its interval is too wide to rank on), and a model with no committed sweep at its d is listed with why.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bcbench.analysis.fewstep import interleaved_medians, one_interleaved_run
from bcbench.analysis.published import (
    Published,
    Sweep,
    committed_eval,
    horizon_text,
    reproduction,
    reproduction_text,
    sweeps_of,
)
from bcbench.analysis.realtime import (
    highest_safe_rate,
    largest_safe_delay,
    rate_text,
    seed_scores,
    step_rate,
    too_few_episodes,
)
from bcbench.analysis.results import Row
from bcbench.modes import EXACT_MODES
from bcbench.protocol import delay_steps as protocol_delay_steps
from bcbench.stats import fmt_estimate, paired_bootstrap

HEADER = ["policy", "setting", "score [95% CI]", "median ms, batch 1 (fastest exact mode)",
          "highest control rate keeping its sync score (at most Push-T's 10 Hz step rate)"]


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
    if (few := too_few_episodes(settings)) is not None:
        return f"too few episodes to decide ({few})"
    safe = {e: largest_safe_delay(settings, e, margin) for e in ("async", "blocking")
            if any(k.startswith(f"realtime-{e}-d") for k in settings)}
    if not safe:
        return "not swept"
    mode, d = max(safe.items(), key=lambda kv: kv[1] or 0)
    if not d:
        return "none shown: no delay swept is shown within the margin of sync"
    rate = highest_safe_rate(d, ms) or 0.0
    return rate_text(rate, f"{mode}, up to d = {d}", step_rate(settings.values()))


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


def _step(realtime: dict[str, dict[str, Any]], step: tuple[float, str]) -> tuple[float, str]:
    """The step rate and task the choice table is capped at: the sweeps', else `step`."""
    return next((step_rate(s.values()) for s in realtime.values()), step)


def _header(top: float, task: str) -> list[str]:
    return [*HEADER[:-1], HEADER[-1].replace("Push-T's 10 Hz", f"{task}'s {top:g} Hz")]


def choose_header(realtime: dict[str, dict[str, Any]], step: tuple[float, str] = (10.0, "Push-T")) -> list[str]:
    """The choice table's header, its last column capped at the task's step rate (`_step`): the Markdown and the
    HTML report print the same one."""
    return _header(*_step(realtime, step))


def control_loop_lines(rows: list[Row], realtime: dict[str, dict[str, Any]], margin: float,
                       paired: dict[str, dict[str, Any]] | None = None,
                       step: tuple[float, str] = (10.0, "Push-T")) -> list[str]:
    """The report's control-loop section; `step`: the study task's step rate and name, where no sweep says it."""
    table = control_loop_rows(rows, realtime, margin, paired)
    top, task = _step(realtime, step)
    header = _header(top, task)
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
            "(the larger safe delay of async and blocking, divided by that call time; the sweeps count delay in "
            f"{task}'s {1 / top:g} s steps, so a rate above {top:g} Hz is shown as {top:g} Hz with what the calls "
            "alone would allow, "
            "and a policy's rate says nothing of how good its score is). The machine is named once, "
            "at the top; each run's training under 'Training: converged?'." + source, "",
            "| " + " | ".join(header) + " |", "|---" * len(header) + "|",
            *("| " + " | ".join(r) + " |" for r in table), ""]


# ----------------------------------------------------------------------------- on this machine (`bcbench choose`)


def delay_steps(latency_ms: float, rate_hz: float) -> int:
    """Control steps a call of `latency_ms` takes at `rate_hz`: d = ceil(L f), at least 1 (a call takes time)."""
    return max(1, protocol_delay_steps(latency_ms / 1e3, rate_hz))


def strategy_at(sweeps: list[Sweep], d: int) -> dict[str, Any] | None:
    """What to run at delay d, from the committed sweeps: naive at the default horizon (the study's own sweep),
    unless another committed strategy or horizon at the same d beats it on the same test seeds by its paired 95%
    interval (lower bound above 0), the rule docs/realtime.md's "which to use" reads; None: nothing swept at d."""
    at_d = [s for s in sweeps if s.at(d) is not None]
    if not at_d:
        return None
    firsts: dict[tuple[str, int | None], Sweep] = {}
    for s in at_d:
        firsts.setdefault((s.strategy, s.horizon), s)
    base = firsts.get(("naive", None)) or next(iter(firsts.values()))
    pick, versus = base, None
    for s in firsts.values():
        if s is base:
            continue
        est, lo, hi, _ = paired_bootstrap(seed_scores(s.at(d)), [seed_scores(base.at(d))])
        if lo > 0 and (versus is None or est > versus[0]):
            pick, versus = s, (est, lo, hi)
    result = pick.at(d)
    return {"strategy": pick.strategy, "horizon": pick.horizon, "horizon_text": horizon_text(pick.horizon, d),
            "score": result["summary"]["mean_score"], "episodes": result["summary"]["n"], "file": str(pick.path),
            "versus_naive": versus, "seeds": seed_scores(result),
            "others": sorted(f"{k[0]} {horizon_text(k[1], d)}" for k, s in firsts.items() if s is not pick)}


def rank(rows: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], str]:
    """The rows that can be ranked, best first, and on what: the committed score at each one's own d where any
    has one; else (nothing swept at these delays) the committed sync score, which the page then says."""
    timed = [r for r in rows if r.get("fastest")]
    ranked = [r for r in timed if r.get("realtime")]
    if ranked:
        return sorted(ranked, key=lambda r: -r["realtime"]["score"]["value"]), "realtime"
    synced = [r for r in timed if r.get("committed")]
    return sorted(synced, key=lambda r: -r["committed"]["value"]), "sync"


def ranked_score(row: dict[str, Any], basis: str) -> dict[str, Any]:
    return row["realtime"]["score"] if basis == "realtime" else row["committed"]


def choice(rows: list[dict[str, Any]], rate_hz: float, cpu: str) -> dict[str, Any]:
    """The answer: the first of `rank`, the runner-up, their paired difference where both were swept on the same
    seeds, and the page's first line."""
    ranked, basis = rank(rows)
    if not ranked:
        return {"line": f"At {rate_hz:g} Hz on {cpu}: no policy has committed evidence to rank (see the table)",
                "chosen": None, "runner_up": None, "basis": basis}
    best, second = ranked[0], (ranked[1] if len(ranked) > 1 else None)
    f = best["fastest"]
    how = (f"score {fmt_estimate(ranked_score(best, basis))} at d = {best['d']} "
           + (f"({best['realtime']['strategy']}, {best['realtime']['horizon_text']})" if basis == "realtime"
              else "(sync score: no committed sweep at these delays)"))
    line = (f"At {rate_hz:g} Hz on {cpu}: use {best['label']} ({best['setting']}, {f['mode']}): {how}; "
            f"median {f['median_ms']:.1f} ms, {f['tail_stat']} {f['tail_ms']:.1f} ms")
    gap = None
    if second is not None:
        line += f". Runner-up: {second['label']}, {fmt_estimate(ranked_score(second, basis))} at d = {second['d']}"
        if basis == "realtime":
            est, lo, hi, n = paired_bootstrap(best["realtime"]["seeds"], [second["realtime"]["seeds"]])
            gap = {"value": est, "ci95": [lo, hi], "pairs": n}
            ahead = "the choice leads it by" if lo > 0 else "not told apart from the choice (choice minus it"
            line += (f"; {ahead} {est:+.3f} [{lo:+.3f}, {hi:+.3f}]{'' if lo > 0 else ')'}, paired over {n} test "
                     "seeds")
    return {"line": line, "chosen": best["label"], "runner_up": second["label"] if second else None,
            "basis": basis, "gap": gap}


def choice_header(rate_hz: float) -> list[str]:
    return ["policy", "setting", "score at d [95% CI]", f"d at {rate_hz:g} Hz", "strategy, horizon",
            "median / tail ms (fastest exact mode)", "x floor", "committed sync score", "re-scored here"]


def with_evidence(m: dict[str, Any], model: Published | None, records: list[tuple[Path, dict[str, Any]]],
                  root: Path, rate_hz: float) -> dict[str, Any]:
    """One policy's row: its measurements here (`m`, from bcbench.evaluation.choose: timings, live episodes), its
    delay d at `rate_hz` from the tail of its fastest exact mode, and the committed evidence of a published model
    (its score, whether the live episodes reproduce it, its real-time score at d). A policy from outside models/
    has its live score only, labelled so."""
    row = dict(m)
    if m.get("fastest"):
        row["d"] = delay_steps(m["fastest"]["tail_ms"], rate_hz)
    live = m.get("live") or {}
    if model is None:
        row["live_only"] = True
        if live:
            row["rescored"] = (f"scored live, {live['episodes']} episodes (wide interval): "
                               f"{fmt_estimate(live['mean_score'])}")
        return row
    committed, estimate = committed_eval(model, root)
    row["committed"] = estimate
    if live:
        rep = reproduction(dict(zip(live["seeds"], live["scores"], strict=True)), committed)
        row["reproduction"], row["rescored"] = rep, reproduction_text(rep)
    if "d" in row:
        row["realtime"] = strategy_at(sweeps_of(model, records), row["d"])
    return row



def choice_rows(rows: list[dict[str, Any]], sources: dict[str, int]) -> list[list[str]]:
    """The printed table and the page's, one row per policy in ranked order then the rest; `sources` numbers
    each sweep file (the page lists them under the table, so that no path widens it)."""
    ranked = rank(rows)[0]
    order = ranked + [r for r in rows if r not in ranked]
    out = []
    for r in order:
        f, rt = r.get("fastest"), r.get("realtime")
        if rt:
            score = f"{fmt_estimate(rt['score'])} [{sources[rt['file']]}]"
            strategy = f"{rt['strategy']}, {rt['horizon_text']}"
        elif r.get("live_only"):
            score, strategy = "-", "-"
        else:
            score, strategy = f"no committed sweep at d = {r.get('d', '?')}", "-"
        timing = f"{f['median_ms']:.1f} / {f['tail_ms']:.1f} ({f['tail_stat']}; {f['mode']})" if f else \
            r.get("timing_error", "not timed")
        floor = f"{r['floor']['x_floor']:.1f}x" if (r.get("floor") or {}).get("x_floor") else "-"
        committed = fmt_estimate(r["committed"]) if r.get("committed") else "-"
        out.append([r["label"], r["setting"], score, str(r.get("d", "-")), strategy, timing, floor, committed,
                    r.get("rescored", "-")])
    return out


def sweep_sources(rows: list[dict[str, Any]]) -> dict[str, int]:
    """Each sweep file the table cites, numbered in order of appearance."""
    out: dict[str, int] = {}
    for r in rank(rows)[0] + rows:
        if r.get("realtime"):
            out.setdefault(r["realtime"]["file"], len(out) + 1)
    return out
