"""`bcbench report RESULTS_DIR`: a Markdown report and a self-contained HTML page with PNG figures.

Reads result files only (evaluations, latencies, training summaries); never trains or evaluates.
Writes RESULTS_DIR/report/{report.md, report.html, fig5_accuracy_vs_latency.png, fig3_denoising_steps.png,
fig4_samplers.png, learning_curves.png} and, for a study with a real-time sweep, realtime.png (score against
delay) and fig5_realtime.png (score under async execution at measured latency).
Beside each of our numbers stand the study's own (measured on an A100 by the study).
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

from bcbench.analysis.accuracy_latency import figure5
from bcbench.analysis.across import is_across, write_across_report
from bcbench.analysis.baseline import HEADER as BASELINE_HEADER
from bcbench.analysis.baseline import baseline_lines, baseline_rows
from bcbench.analysis.choose import choose_header, control_loop_lines, control_loop_rows
from bcbench.analysis.compute import timing_sittings
from bcbench.analysis.convergence import NO_CHECK, NOT_CONVERGED, apply_checks, check_lines, doubling_checks
from bcbench.analysis.fewstep import fewstep_lines, load_paired, one_interleaved_run
from bcbench.analysis.figures import drop_undrawn, figure3, figure4, figure5_realtime, learning_curves, realtime_figure
from bcbench.analysis.findings import DEFAULT_MARGIN, Finding, judge, points_from_rows, shared_timing, with_interleaved
from bcbench.analysis.provenance import MACHINES_HEADER, lead_line, machine_rows, paired_conditions, provenance_notes
from bcbench.analysis.report_realtime import REALTIME_COLUMNS as REALTIME_COLUMNS  # the real-time section, re-exported
from bcbench.analysis.report_realtime import realtime_lines
from bcbench.analysis.report_realtime import realtime_table as realtime_table
from bcbench.analysis.report_realtime import same_as_fixed as same_as_fixed
from bcbench.analysis.results import (
    Row,
    cpu_text,
    file_commits,
    load_check_rows,
    load_realtime,
    load_rows,
    same_cpu_once,
    study_machines,
    study_time,
    weights_conflicts,
)
from bcbench.analysis.seeds import merge_training_seeds, per_seed_cell
from bcbench.analysis.strategies import load_strategy_sweeps, strategy_figure, strategy_lines
from bcbench.analysis.studies import (
    informed_sentence,
    left_out,
    mixing_reason,
    preset_choices,
    study_dirs,
    study_spec,
    test_informed_lines,
)
from bcbench.analysis.tables import html_image, html_table, md_table
from bcbench.reference import CPU_DEVIATIONS, STUDY_REFERENCE
from bcbench.stats import fmt_estimate, fmt_share
from bcbench.utils.io import atomic_path

FIG5 = "Figure 5: accuracy against inference time"
FIG5_ZOOM = "Figure 5, zoomed: the generative settings (the dashed box)"
COLUMNS = ["policy", "params", "mean score [95% CI]", "> 0.5 [Wilson 95%]", "> 0.9 [Wilson 95%]",
           "success [Wilson 95%]",
           "latency ref. median / tail (ms; tail = p99 from >= 100 calls, else max of N)",
           "latency fast median (ms; x this machine's floor)", "max rate, every-step re-plan (Hz)",
           "study (A100): score / >0.5 / >0.9 / ms"]  # training and hardware: once per run, not on every row


def _ms(v: float | None) -> str:
    return "-" if v is None else (f"{v:.1f}" if v >= 10 else f"{v:.2f}")


def _study_cell(r: Row) -> str:
    ref = STUDY_REFERENCE.get(r.reference_key)
    if not ref:
        return "-"
    parts = []
    for key, pct in (("score", False), ("gt05", True), ("gt09", True)):
        v = ref.get(key)
        parts.append("-" if v is None else (f"{100 * v:.1f}%" if pct else f"{v:.2f}"))
    parts.append(_ms(ref.get("latency_ms")))
    return " / ".join(parts)


def _same_cpu_once(segs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Training sessions' CPUs with a session recorded before cpu_id existed folded into one of the same model,
    flags and precision that has it (the same machine), so one CPU is not named twice."""
    return same_cpu_once(segs, lambda g: (g.get("cpu_model"), tuple(g.get("cpu_flags") or ()), g.get("precision")))


def _train_cell(r: Row) -> str:
    t = r.train
    if not t:
        return "none (baseline)"
    seconds = t.get("train_time_s") or t.get("train_time_s_this_session") or 0
    # the summary's samples/s is its last session's; a run resumed across sessions states its overall rate too,
    # so minutes and samples/s agree (an earlier session that shared its machine trained slower)
    last, overall = t.get("samples_per_s"), (t["samples"] / seconds if seconds and t.get("samples") else None)
    cell = f"{t.get('epochs', 0):.2f} epochs, {seconds / 60:.1f} min"
    if overall and last and abs(overall / last - 1) > 0.05:
        cell += f", {overall:.0f} samples/s overall ({last:.0f} in its last session)"
    elif last:
        cell += f", {last:.0f} samples/s"
    if t.get("stopped") not in (None, "finished"):
        cell += f" ({t['stopped']})"  # e.g. "stopped by time: schedule not finished"
    # where it trained: every session's CPU (segments), else the summary's machine; samples/s depend on it
    segs = t.get("segments") or ([{**t["hardware"], "precision": t.get("precision")}] if t.get("hardware") else [])
    machines = sorted({cpu_text(g) + (f", {g['precision']}" if g.get("precision") else "")
                       for g in _same_cpu_once(segs)})
    return cell + (f"; trained on {' and '.join(machines)}" if machines else "")


def _fast_cell(fast: dict[str, Any]) -> str:
    """The fast mode's median, with its ratio to this machine's floor where the record has one."""
    ratio = fast.get("x_floor")
    return _ms(fast.get("median_ms")) + ("" if ratio is None else f" ({ratio:.1f}x)")


SEEDS_NOTE = ("A setting trained with several training seeds shows the mean over seeds of each seed's mean score, "
              "with a t interval over the training seeds' means (k - 1 degrees of freedom: with 3 seeds t = 4.30, "
              "so it is wide; never narrower than the interval the episodes alone give), which keeps its 95% "
              "coverage; the two-level bootstrap's interval (seeds and, within each, episodes resampled) is shown "
              "beside it, but with 3 seeds it covers the true mean only "
              "80-85% of the time when training seeds carry most of the variance (simulated: "
              "results/seed-intervals/). Each seed's score and the share of the variance that training seeds carry "
              "are beside it. Shares pool the episodes of every seed; their Wilson intervals treat those episodes as "
              "independent, so they leave out the spread between seeds. Paired comparisons pair episodes within "
              "each training seed and take the t interval over the training seeds' paired differences; verdicts "
              "read that interval. ")


def table_rows(rows: list[Row], multi: bool = False) -> list[list[str]]:
    out = []
    order = ["random", "scripted", "cnn_mlp", "resnet50", "bet", "bct", "diffusion", "flow"]
    for r in sorted(rows, key=lambda r: (order.index(r.policy) if r.policy in order else 99, r.label,
                                          r.sampler or "", r.steps or 0)):
        ref = r.latency.get("reference") or {}
        tail = "-" if not ref else f"{_ms(ref.get('tail_ms', ref.get('p99_ms')))} ({ref.get('tail_stat', 'p99')})"
        fast = r.latency.get("fast", {})
        rate = fast.get("max_rate_every_step_hz") or (r.latency.get("reference") or {}).get("max_rate_every_step_hz")
        name = r.setting
        out.append([name, f"{r.params / 1e6:.2f} M", fmt_estimate(r.est("mean_score")),
                    *([per_seed_cell(r)] if multi else []),
                    *(fmt_share(r.est(k), int(r.summary.get("n") or len(r.scores)))
                      for k in ("share_above_0.5", "share_above_0.9", "success_rate")),
                    f"{_ms(r.latency_ms('reference'))} / {tail}",
                    _fast_cell(fast), "-" if rate is None else f"{rate:.1f}", _study_cell(r)])
    return out


FINDINGS_INTRO = ("Each verdict rests on paired comparisons: per-seed score differences of two settings evaluated on "
                  "the same episode seeds, with a 95% paired-bootstrap interval of their mean (over several training "
                  "seeds: a t interval over the seeds' mean differences), against an equivalence "
                  "margin of {m} mean score. Supported: the interval lies inside the margin or beyond it in the "
                  "claimed direction; contradicted: wholly on the other side; inconclusive: otherwise.")


def _spacing_note(rows: list[Row]) -> str:
    spacings = sorted({r.spacing for r in rows if r.spacing})
    if not spacings:
        return ""
    return ("Diffusion Policy timestep spacing: " + ", ".join(spacings) + " (trailing: every step count starts "
            "from pure noise at t = 99; leading: diffusers' and the study's default, which starts K = 1 at t = 0 "
            "and K = 40 at t = 78; variants marked -LEADING use it).")


def time_lines(results: Path) -> list[str]:
    """Where the study's time went (summed work, not wall time: a study may be stopped and resumed)."""
    spent = study_time(results)
    if not any(spent.values()):
        return []
    budget = sum(v for k, v in spent.items() if k != "real-time sweep")
    parts = ", ".join(f"{k} {v / 60:.0f} min" for k, v in spent.items() if v)
    total = f"; with the real-time sweep: {sum(spent.values()) / 3600:.2f} h" if spent["real-time sweep"] else ""
    machines = study_machines(results)
    return ["## Study time", "", f"{parts}. Training, evaluation and timing: {budget / 3600:.2f} h{total} (sums "
            "of recorded work; a run resumed after other work shared its machine records that slower time). "
            f"Machines: {'; '.join(machines) if machines else 'not recorded'}.", ""]


def deviation_lines(rows: list[Row]) -> list[str]:
    """How each cpu-preset policy departs from its paper: the network (bcbench.reference; runs also record a copy,
    which went stale once and is not read here) and the recipe each of its runs trained with (its own config)."""
    cpu = sorted({r.policy for r in rows if (r.preset or "").startswith("cpu") and r.policy in CPU_DEVIATIONS})
    if not cpu:
        return []

    def recipes(policy: str) -> str:
        found = list(dict.fromkeys(r.recipe for r in rows if r.policy == policy and r.recipe))
        return f"; trained as run: {' / '.join(found)}" if found else ""

    return ["## Deviations from the papers' recipes (cpu presets)", "",
            *[f"- {p}: {CPU_DEVIATIONS[p]}{recipes(p)}" for p in cpu], *preset_change_lines(rows), ""]


# not recipe changes: how a run is kept, and its budget (the recipe line and the training column state it)
_NOT_RECIPE = {"optim.checkpoint_every", "seed", "optim.max_steps", "optim.epochs"}


def preset_change_lines(rows: list[Row]) -> list[str]:
    """A line per trained setting that overrode its preset (a study's `set`): the overrides and the preset's own
    values, both as its run.json records them; said once however many variants and training seeds share it."""
    lines = []
    for r in rows:
        changed = sorted(k for k in r.overrides if k not in _NOT_RECIPE
                         and not (k == "optim.val_every" and "plateau" not in r.recipe))  # read by plateau only
        if changed and r.preset:
            lines.append(f"- {r.label} changes its {r.preset} preset: " + ", ".join(
                f"{k} {r.overrides[k]} (preset {r.preset_values.get(k, 'not recorded')})" for k in changed))
    return list(dict.fromkeys(lines))


def convergence_lines(rows: list[Row]) -> list[str]:
    """One line per trained run: converged, not converged, or not shown converged (its twice-the-steps check; in
    older studies its learning curve), and why. A label trained with several seeds names each line's training seed
    (one seed per label needs no name)."""
    seeds: dict[str, set[int]] = {}
    for r in rows:
        if r.train_seed is not None:
            seeds.setdefault(r.label, set()).add(r.train_seed)
    seen, out = set(), []
    for r in rows:
        run = r.key.split(":")[0]
        if r.converged is None or run in seen:
            continue
        seen.add(run)
        # a run awaiting its check, or whose check is inconclusive, is not shown converged, which is not the same
        # as failing it (a check's interval wholly above the margin; in older studies, the curve rule)
        curve_rule = r.check_verdict is None and not r.convergence.startswith(NO_CHECK)
        failed = r.check_verdict == NOT_CONVERGED or curve_rule
        state = "converged" if r.converged else "**not converged**" if failed else "**not shown converged**"
        seed = f" (training seed {r.train_seed})" if len(seeds.get(r.label, ())) > 1 else ""
        out.append(f"- {r.label}{seed}: {state}: {r.convergence}; {_train_cell(r)}")
    return out or ["- no trained runs"]


def write_report(results: str | Path, extra_dirs: list[str] | None = None) -> dict[str, str]:
    results = Path(results)
    if is_across(results):  # one study per task, read side by side
        return write_across_report(results)
    spec = study_spec(results)  # read once: for a combined report it reads every study's spec.json
    margin = spec.get("margin", DEFAULT_MARGIN)
    rows = load_rows(results, extra_dirs, margin)
    check_rows = load_check_rows(results)  # a confirm study compares on validation episodes, apart from its table
    checks = doubling_checks(check_rows or rows, margin)
    strict = bool(spec.get("purpose"))  # studies under the seed protocol need the check
    verdicts = apply_checks(rows, checks, strict, margin)
    # one row per setting from here on (several training seeds merged); `rows` keeps one per run for training
    settings = merge_training_seeds(rows)
    out = results / "report"
    out.mkdir(parents=True, exist_ok=True)
    # latency timed in interleaved rounds, per inference mode, where the study's folder has it: the findings' times
    # and Figure 5's axis (reference mode), and finding 3's DDIM/DDPM ratios (any mode's where reference has none)
    paired = load_paired(results)
    realtime, strategies = load_realtime(results), load_strategy_sweeps(results)
    fig5, figs = _figures(out, settings, rows, paired, realtime, strategies)
    ratio_file = paired.get("reference") or next(iter(paired.values()), {})
    findings = judge(with_interleaved(points_from_rows(settings), paired.get("reference")), margin,
                     ratio_file.get("ratios"))
    multi = any(r.seed_scores for r in settings)
    columns = [*COLUMNS[:3], "per training seed", *COLUMNS[3:]] if multi else COLUMNS
    table = table_rows(settings, multi)
    task = spec.get("task") or "pusht"
    step = (float(spec.get("rate_hz", 10.0)), "Push-T" if task == "pusht" else task)
    intro = _intro(task, multi, rows)
    informed = test_informed_lines(results)
    warnings = weights_conflicts(results)
    notes = preset_choices(results) + informed + warnings
    notes += provenance_notes(rows, file_commits(results, extra_dirs), mixing_reason(results))
    notes += paired_conditions(paired, shared_timing(settings, paired.get("reference")))
    lead = lead_line(_study_name(results, spec.get("name"), task), settings,
                     mixed=any("mix several commits" in n for n in notes), runs=rows)
    trained = [r for r in rows if r.converged is not None]
    if trained and not any(r.converged for r in trained):
        lead += (" None of its trained models is shown converged (smoke-sized or short trainings: see 'Training: "
                 "converged?'): read its scores as a check of the pipeline, not of the policies.")
    machines = machine_rows(rows)
    machines_md = ["## Machines", "", md_table(MACHINES_HEADER, machines), ""] if machines else []
    md = ["# bcbench report", "", lead, "",
          *([f"![{FIG5}]({fig5.name})", ""] if fig5 else []),
          *control_loop_lines(settings, realtime, margin, paired, step),
          *([informed_sentence(informed), ""] if informed else []),
          *machines_md, "## The study's findings on this evidence", "", FINDINGS_INTRO.format(m=margin), ""]
    md += [f"{f.number}. **{f.claim}**: *{f.verdict}*. {f.evidence}  \n   Rule: {f.rule}" for f in findings]
    versus = baseline_rows(settings, realtime)  # each learned policy against the scripted baseline
    md += ["", *baseline_lines(settings, versus), "## Results", "", md_table(columns, table), "",
           "## Training: converged?", "", *convergence_lines(rows), "",
           *check_lines(verdicts, strict, margin, validation=bool(check_rows)),
           *deviation_lines(rows),
           *fewstep_lines(points_from_rows(settings, "fast"), margin, paired=paired.get("fast"),
                          sittings=timing_sittings(results)),
           *time_lines(results),
           *realtime_lines(realtime, margin, rows), *strategy_lines(strategies, margin)]
    for title, path in figs.items():
        if path:
            md += [f"## {title}", "", f"![{title}]({path.name})", ""]
    md += ["## How to read the numbers", "", intro, "", "## Provenance", "", *[f"- {n}" for n in notes], ""]
    md_path = out / "report.md"
    with atomic_path(md_path) as tmp:
        tmp.write_text("\n".join(md) + "\n")
    html_path = out / "report.html"
    with atomic_path(html_path) as tmp:
        choose = control_loop_rows(settings, realtime, margin, paired)
        under = informed_sentence(informed) if informed else ""
        top = ((html_image(FIG5, fig5, "lead", _lead_height(lead, choose, under)) if fig5 else "")
               + "<h2>Which policy for my control loop</h2>" + html_table(choose_header(realtime, step), choose)
               + (f"<p>{html.escape(under)}</p>" if under else "")
               + ("<h2>Machines</h2>" + html_table(MACHINES_HEADER, machines) if machines else ""))
        tail = (f"<h2>How to read the numbers</h2><p>{html.escape(intro)}</p><h2>Provenance</h2><ul>"
                + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>")
        findings_html = _findings_html(findings, FINDINGS_INTRO.format(m=margin)) + (
            "<h2>Against the scripted baseline</h2>" + html_table(BASELINE_HEADER, versus) if versus else "")
        tmp.write_text(_html(lead.replace("`", ""), findings_html, (columns, table), figs, convergence_lines(rows),
                             top, tail))
    return {"markdown": str(md_path), "html": str(html_path), "dir": str(out), "warnings": warnings}


def _figures(out: Path, settings: list, rows: list, paired: dict, realtime: list, strategies: list) -> tuple:
    """Figure 5 and the report's other figures, by title (a figure with nothing to draw is None)."""
    names = ("fig5_accuracy_vs_latency", "fig5_zoom", "fig3_denoising_steps", "fig4_samplers", "learning_curves",
             "realtime", "fig5_realtime", "strategies")
    path = {n: out / f"{n}.png" for n in names}
    # the report opens with Figure 5 (and which policy suits which control loop); its zoom leads the other figures
    fig5, zoom = figure5(settings, path["fig5_accuracy_vs_latency"], timing=paired.get("reference"),
                         run=one_interleaved_run(paired), zoom_path=path["fig5_zoom"])
    figs = {FIG5_ZOOM: zoom,
            "Figure 3: generative policies against sampling steps": figure3(settings, path["fig3_denoising_steps"]),
            "Figure 4: DDPM-cosine, DDIM-cosine, DDIM-linear": figure4(settings, path["fig4_samplers"]),
            "Learning curves": learning_curves(rows, path["learning_curves"])}
    if realtime:
        figs["Score under real-time execution"] = realtime_figure(realtime, path["realtime"])
        figs["Figure 5, real time"] = figure5_realtime(realtime, path["fig5_realtime"])
        figs["Execution strategies: score against delay"] = strategy_figure(strategies, path["strategies"])
    drop_undrawn(path.values(), (fig5, *figs.values()))
    return fig5, figs


def _intro(task: str, multi: bool, rows: list) -> str:
    """'How to read the numbers': what a score is on this task, what a latency is, and the runs' spacing."""
    pusht_scores = ("Scores: mean over the evaluation episodes of the max reward min(coverage/0.95, 1), with 95% "
                    "bootstrap intervals. ")
    scores = pusht_scores if task == "pusht" else (
        f"Task {task}: an episode scores 1 when it succeeds at any step, else 0, so the mean score is the success rate "
        "(its Wilson interval under 'success'); the study's A100 numbers are Push-T's and stand beside no row here. ")
    return (scores + (SEEDS_NOTE if multi else "")
            + "Latency: one call at batch 1, raw observation in, chunk out (median, and the p99 from at "
            "least 100 calls or else the maximum, labelled 'max of N'). The study's numbers were measured by the "
            "study on an A100; ours on the hardware named at the top. " + _spacing_note(rows))


def _study_name(results: Path, name: str | None, task: str) -> str:
    """The lead line's study name, with its task and the studies it combines (and what it leaves out of them)."""
    sources = [d.name for d in study_dirs(results) if d != results]
    # labels quoted and joined with "and": a label with a comma in it ("ResNet-50 CNN, twice the steps") reads as two
    leaving = [f"; leaves out {' and '.join(repr(x) for x in labels)} of {study}"
               for study, labels in left_out(results).items()]
    return (name or results.name) + (f" on {task}" if task != "pusht" else "") + (
        f" (combines {', '.join(sources)}{''.join(leaving)})" if sources else "")


# A choice-table row's height in Chromium at 1280 x 900 (scripts/check_report.py): every row of every committed
# report's table measured 35 px, two lines, the header's too (its long last column and the policies' labels wrap).
ROW_PX = 35


def _lead_height(intro: str, rows: list[list[str]], under: str = "") -> str:
    """Figure 5's height cap, so that it and the choice table fit the first screen: 46% of the window less what a
    table of more than 4 rows (ROW_PX each, 18 px more for each further line a long row wraps to, about 150
    characters a line at a laptop's width), an introduction of more than 3 lines and a sentence under the table
    (about 22 px per 170 characters) take, never below 18% of the window (the table, the answer, comes first)."""
    wrapped = sum(-(-sum(len(c) for c in r) // 150) - 1 for r in rows)
    extra = (ROW_PX * max(0, len(rows) - 4) + 18 * wrapped + 22 * max(0, -(-len(intro) // 170) - 3)
             + 22 * -(-len(under) // 170))
    return f"max-height:max(18vh, calc(46vh - {extra}px))" if extra else ""


def _findings_html(findings: list[Finding], rules_intro: str) -> str:
    items = "".join(
        f"<li><b>{html.escape(f.claim)}</b>: <span class='{f.verdict.split()[0]}'>{html.escape(f.verdict)}</span>. "
        f"{html.escape(f.evidence)}<br><i>Rule: {html.escape(f.rule)}</i></li>" for f in findings)
    return f"<h2>The study's findings on this evidence</h2><p>{html.escape(rules_intro)}</p><ol>{items}</ol>"


def _html(intro: str, findings: str, table: tuple[list[str], list[list[str]]], figs: dict[str, Path | None],
          training: list[str], lead: str, tail: str) -> str:
    # the first screen holds Figure 5 and the table under it (.lead: the figure's height capped for that)
    css = ("body{font-family:system-ui,sans-serif;max-width:1400px;margin:0 auto 2em;padding:0 1em;color:#222}"
           "h1{font-size:1.6em;margin:.4em 0 .2em}h2{font-size:1.25em;margin:.5em 0 .3em}"
           "img.lead{max-height:46vh;width:auto}"
           "table{border-collapse:collapse;font-size:12px}td,th{border:1px solid #ccc;padding:3px 6px;text-align:left}"
           "th{background:#f3f3f3}.supported{color:#176b2c}.contradicted{color:#a11}.inconclusive{color:#8a6d00}"
           ".undertrained{color:#666}"
           "img{max-width:100%;border:1px solid #eee}")
    train_items = "".join(f"<li>{html.escape(t[2:].replace('**', ''))}</li>" for t in training)
    images = "".join(html_image(title, path) for title, path in figs.items() if path)
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>bcbench report</title><style>{css}</style>"
            f"</head><body><h1>bcbench report</h1><p>{html.escape(intro)}</p>{lead}{findings}<h2>Results</h2>"
            f"{html_table(*table)}<h2>Training: converged?</h2><ul>{train_items}</ul>{images}{tail}"
            "</body></html>\n")
