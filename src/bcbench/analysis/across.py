"""A report across tasks: one table of policy x task, and the study's findings re-read on each task.

`bcbench report DIR` on a folder holding `across.json` reads the study folders it names (each a study's own folder
or a combined report's, each on one task) side by side:

    {"tasks": ["../metaworld-explore-1", "../metaworld-explore-1-peg"],    # one folder per task, in this order
     "demos": "../metaworld-demos",                                         # optional: the generated stores' records
     "difficulty": {"metaworld/drawer-open": "easy"},   # optional: only for records written before they held it
     "more_demos": {"metaworld/peg-insert-side": "../metaworld-explore-5-peg"},  # optional (analysis.whynot)
     "larger_frame": {"metaworld/pick-place": "../metaworld-explore-6-pick128"},  # optional (analysis.whynot)
     "why": "what the reader gets from reading them together"}

Each folder keeps its own report (Figure 5, Figure 3, learning curves, its findings in full); this one holds what
only a side-by-side reading shows: per task the success of every policy setting with its interval and training-seed
count and its latency at batch 1 in the fastest exact mode timed (and when each task's timings ran, sitting by
sitting: analysis.compute); the findings' verdicts per task (their rules
unchanged: `bcbench.analysis.findings`); per task whether the best setting reaches the issue's 80% and where image
Diffusion Policy stands against 3D Diffusion Policy's image-DP number for the task's difficulty group, and for a task
under 80% what its files say of why (its twice-the-steps check; a stage with more demonstrations; one with larger
frames: analysis.whynot).
Reads result files only.
"""

from __future__ import annotations

import html
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bcbench.analysis.accuracy_latency import figure5
from bcbench.analysis.across_cells import (
    ORDER,
    baseline,
    common_parts,
    latency_cell,
    setting_key,
    setting_name,
    success,
    success_cell,
    without,
)
from bcbench.analysis.compute import cost_table, sittings_text
from bcbench.analysis.figures import drop_undrawn, figure3
from bcbench.analysis.findings import DEFAULT_MARGIN, Finding, judge, points_from_rows
from bcbench.analysis.results import Row, file_commits, load_rows
from bcbench.analysis.seeds import merge_training_seeds
from bcbench.analysis.studies import ACROSS_FILE, informed_sentence, study_spec, test_informed_lines
from bcbench.analysis.tables import html_image, html_table, md_table
from bcbench.analysis.whynot import STAGE_KINDS, stage_folders, why_not_lines
from bcbench.errors import BCBenchError
from bcbench.protocol import held_out_episodes
from bcbench.reference import IMAGE_DP_3DDP
from bcbench.utils.io import atomic_path, read_json

GOAL = 0.80  # issue 75: the best policy on every task at >= 80% success over 3 training seeds
KEYS = {"tasks", "demos", "difficulty", "why", *STAGE_KINDS}  # what across.json may hold


@dataclass
class TaskColumn:
    """One task's study folder read back: its settings (one row per setting, training seeds merged)."""

    folder: Path
    task: str
    difficulty: str | None
    purpose: str
    settings: list[Row]
    findings: list[Finding]
    commits: list[str]


def is_across(results: str | Path) -> bool:
    return (Path(results) / ACROSS_FILE).is_file()


def read_across(results: Path) -> tuple[dict[str, Any], list[TaskColumn]]:
    """across.json validated, and each task's folder read back."""
    f = results / ACROSS_FILE
    spec = read_json(f)
    names = spec.get("tasks") if isinstance(spec, dict) else None
    if not isinstance(names, list) or len(names) < 1 or not all(isinstance(n, str) and n for n in names):
        raise BCBenchError(f"{f}: 'tasks' must list the study folders it reads, one per task (paths relative to it)")
    unknown = sorted(set(spec) - KEYS)
    if unknown:  # a misspelt key ("more_demo") would otherwise leave its stages out of the report without a word
        raise BCBenchError(f"{f}: unknown key(s) {', '.join(map(repr, unknown))}; across.json takes "
                           f"{', '.join(sorted(KEYS))}")
    if "demos" in spec and not (isinstance(spec["demos"], str) and spec["demos"]):
        raise BCBenchError(f"{f}: 'demos' names the folder of the demonstration records (a path relative to it)")
    stated = spec.get("difficulty", {})
    if not isinstance(stated, dict) or not all(isinstance(v, str) for v in stated.values()):
        raise BCBenchError(f"{f}: 'difficulty' maps a task name to its difficulty group (for records without one)")
    columns = [_column(results / n, f, stated) for n in names]
    seen: dict[str, Path] = {}
    for c in columns:
        if c.task in seen:
            raise BCBenchError(f"{f}: {seen[c.task].name} and {c.folder.name} are both on {c.task}; name one folder "
                               "per task (a combined report's folder joins the studies of one task)")
        seen[c.task] = c.folder
    return spec, columns


def _column(folder: Path, f: Path, stated: dict[str, str]) -> TaskColumn:
    if not ((folder / "spec.json").is_file() or (folder / "combine.json").is_file()):
        raise BCBenchError(f"{f} names {folder.name}, which is not a study or combined report folder")
    spec = study_spec(folder)
    margin = spec.get("margin") or DEFAULT_MARGIN
    rows = load_rows(folder, None, margin)
    settings = merge_training_seeds(rows)
    task = spec.get("task") or "pusht"
    recorded = {r.difficulty for r in rows} - {None}
    if len(recorded) > 1 or (recorded and task in stated and stated[task] not in recorded):
        raise BCBenchError(f"{f}: {task}'s records name difficulty {', '.join(sorted(recorded))}"
                           + (f", across.json {stated[task]}" if task in stated else ""))
    difficulty = next(iter(recorded), stated.get(task))
    return TaskColumn(folder, task, difficulty, spec.get("purpose") or "", settings,
                      judge(points_from_rows(settings), margin), sorted(file_commits(folder)))


def table(columns: list[TaskColumn]) -> tuple[list[str], list[list[str]], list[str]]:
    """policy setting x task: success [interval], training seeds; latency at batch 1 (fastest exact mode timed); and
    the parts of a name every learned row shares, left out of its rows (`common_parts`)."""
    by_key: dict[tuple[str, str], dict[str, Row]] = {}
    first: dict[tuple[str, str], Row] = {}
    for c in columns:
        for r in c.settings:
            by_key.setdefault(setting_key(r), {})[c.task] = r
            first.setdefault(setting_key(r), r)
    order = sorted(by_key, key=lambda k: (ORDER.index(first[k].policy) if first[k].policy in ORDER else 99, k))
    header = ["policy", *(f"{c.task} ({c.difficulty or '-'})" for c in columns)]
    labels = {k: setting_name(list(by_key[k].values())) for k in order}  # (label, variant suffix)
    learned = [k for k in order if not baseline(first[k])]
    shared = common_parts([labels[k][0] for k in learned])
    names = {k: (without(labels[k][0], shared) if k in learned else labels[k][0]) + labels[k][1] for k in order}
    full = {k: "".join(labels[k]) for k in order}
    if len(set(names.values())) < len(names) == len(set(full.values())):  # dropping the shared parts made two
        shared, names = [], full  # settings read alike (their parts in another order): keep every part
    rows = [[names[k],
             *(f"{success_cell(by_key[k][c.task])}; {latency_cell(by_key[k][c.task])}" if c.task in by_key[k] else "-"
               for c in columns)] for k in order]
    ref = [IMAGE_DP_3DDP.get(c.difficulty or "") for c in columns]
    if any(v is not None for v in ref):
        rows.append(["3D Diffusion Policy's image DP, 10 demos (its difficulty group's mean; published)",
                     *("-" if v is None else f"{100 * v:.1f}%" for v in ref)])
    return header, rows, shared


def findings_table(columns: list[TaskColumn]) -> tuple[list[str], list[list[str]]]:
    header = ["finding", *(c.task for c in columns)]
    claims = {f.number: f.claim for c in columns for f in c.findings}
    verdicts = {(c.task, f.number): f.verdict + ("" if f.evaluated else " (not evaluated)")
                + (f" (at the {f.bound}: nothing to separate)" if f.bound else "")
                for c in columns for f in c.findings}
    return header, [[f"{n}. {claims[n]}", *(verdicts.get((c.task, n), "-") for c in columns)] for n in sorted(claims)]


def trained_on(r: Row, kept: int | None) -> int | None:
    """The demonstrations a run trained on: its `demos`, else its store's kept episodes less the held-out split
    (the split's rule, `bcbench.protocol.held_out_episodes`), where the store's record is given; None where neither
    is known."""
    if r.data_split.get("demos"):
        return int(r.data_split["demos"])
    return None if kept is None else kept - held_out_episodes(kept, float(r.data_split.get("val_fraction", 0.1)))


def learned_settings(c: TaskColumn) -> list[Row]:
    """The task's trained settings (one training seed or several), not the baselines."""
    return [r for r in c.settings if not baseline(r)]


def best_setting(c: TaskColumn) -> Row | None:
    """The task's learned setting with the highest success (None: nothing learned evaluated yet)."""
    learned = learned_settings(c)
    return max(learned, key=lambda r: success(r)[0]) if learned else None


def why_lines(columns: list[TaskColumn], stages: dict[str, dict[str, Path]]) -> list[str]:
    """For each task whose best setting is under the goal, what its files say of why (analysis.whynot; `stages`:
    kind -> task -> explore folder)."""
    return [why_not_lines(c.folder, c.task, best, {k: v[c.task] for k, v in stages.items() if c.task in v})
            for c in columns
            if (best := best_setting(c)) is not None and success(best)[0] < GOAL]


def goal_lines(columns: list[TaskColumn], kept: dict[str, int] | None = None) -> list[str]:
    """Per task: the best setting's success against the 80% goal (point estimate and interval), and image DP against
    3D-DP's group number, compared only where it trained on their 10 demonstrations (`kept`: each task's store
    size, from the records across.json names)."""
    kept = kept or {}
    out = []
    for c in columns:
        best = best_setting(c)
        if best is None:
            continue
        learned = learned_settings(c)
        v, lo, _, _ = success(best)
        seeds = len(best.seed_scores) or 1
        verdict = (f"its whole interval is at or above {GOAL:.0%}" if lo >= GOAL else
                   f"its point estimate is at or above {GOAL:.0%}, its interval reaches below" if v >= GOAL else
                   f"its point estimate is below {GOAL:.0%}")
        line = (f"- **{c.task}**: best {best.setting} {success_cell(best)}: {verdict}"
                + ("" if seeds >= 3 else f" (on {seeds} training seed{'s' if seeds > 1 else ''}; the goal reads 3)"))
        ref = IMAGE_DP_3DDP.get(c.difficulty or "")
        dps = [r for r in learned if r.policy == "diffusion"]
        if ref is not None and dps:
            line += "; " + _against_3ddp(max(dps, key=lambda r: success(r)[0]), ref, c, kept.get(c.task))
        out.append(line + ".")
    return out


def _against_3ddp(dp: Row, ref: float, c: TaskColumn, kept: int | None) -> str:
    n = trained_on(dp, kept)
    v, lo, hi, _ = success(dp)
    theirs = f"3D Diffusion Policy's image-DP {100 * ref:.1f}% (the {c.difficulty} group's mean, 10 demonstrations)"
    if n != 10:
        return (f"image DP's best here ({dp.setting}, {100 * v:.1f}%) trained on "
                f"{'an unrecorded number of' if n is None else n} demonstrations: not comparable with {theirs}")
    side = ("above" if lo > ref else "below" if hi < ref else "not separated from")
    return (f"image DP's best here on 10 demonstrations ({dp.setting}, {100 * v:.1f}% [{100 * lo:.1f}, "
            f"{100 * hi:.1f}]) is {side} {theirs}; one task against a group's mean, under bcbench's protocol, "
            "not theirs")


def _rel(target: Path, start: Path) -> str:
    return Path(os.path.relpath(target, start)).as_posix()


def figure_lines(columns: list[TaskColumn], out: Path) -> tuple[list[str], dict[str, Path]]:
    """Per task a link to its own report, and its Figure 5 (success against latency; only where its study timed)
    and Figure 3 (against denoising steps; only where it evaluated several), drawn here from its settings."""
    lines, figs = [], {}
    for c in columns:
        slug = c.task.replace("/", "-")
        lines.append(f"- {c.task}: [its report]({_rel(c.folder / 'report' / 'report.md', out)})")
        target = {"Figure 5": out / f"fig5_{slug}.png", "Figure 3": out / f"fig3_{slug}.png"}
        drawn = {"Figure 5": figure5(c.settings, target["Figure 5"])[0],
                 "Figure 3": figure3(c.settings, target["Figure 3"])}
        for title, path in drawn.items():
            if path:
                lines.append(f"  ![{title}, {c.task}]({path.name})")
                figs[f"{title}, {c.task}"] = path
        drop_undrawn(target.values(), drawn.values())
        missing = [text for title, text in (("Figure 5", "no Figure 5: its study timed nothing"),
                                            ("Figure 3", "no Figure 3: fewer than two step counts of a generative "
                                                         "policy")) if not drawn[title]]
        if missing:
            lines.append(f"  ({'; '.join(missing)})")
    return lines, figs


def lead(spec: dict[str, Any], columns: list[TaskColumn], name: str) -> str:
    purposes = {c.purpose for c in columns}
    seeds = sorted({s for c in columns for r in c.settings for sc in (r.seed_scores or [r.scores]) for s in sc})
    span = f"episode seeds {seeds[0]}-{seeds[-1]}" if seeds else "no episodes"
    kind = (" (validation: they make choices; they are not reported scores)" if purposes == {"explore"} else
            " (test)" if purposes == {"confirm"} else " (validation and test: see each task's report)")
    n = sorted({int(r.summary.get("n") or 0) // max(len(r.seed_scores), 1) for c in columns for r in c.settings})
    why = f" {spec['why']}" if spec.get("why") else ""
    return (f"{name}: {len(columns)} task{'s' if len(columns) > 1 else ''} "
            f"({', '.join(c.task for c in columns)}), on {span}{kind}, {'/'.join(map(str, n))} episodes a setting "
            f"and training seed.{why}")


def write_across_report(results: str | Path) -> dict[str, Any]:
    results = Path(results)
    spec, columns = read_across(results)
    out = results / "report"
    out.mkdir(parents=True, exist_ok=True)
    head, rows, shared = table(columns)
    fhead, frows = findings_table(columns)
    top = lead(spec, columns, results.name)
    records = demo_records(results, spec, columns)
    demos = _demo_lines(records, columns)
    goals = goal_lines(columns, {t: int(d["kept"]) for t, d in records.items()})
    stages = stage_folders(results, spec, [c.task for c in columns])
    whys = why_lines(columns, stages)
    why_head = (f"Why under {GOAL:.0%}, per task below it: the best setting's twice-the-steps check (and the task's "
                "other policies'), then a stage that trained the same policy on more demonstrations"
                + (", then one that showed it larger frames" if stages.get("larger_frame") else "")
                + ", paired with the confirm run on its check base's validation episodes (one training seed each: "
                "evidence on a cause, not a reported score).")
    fig_lines, figs = figure_lines(columns, out)
    explored = [(f.name, f) for by_task in stages.values() for f in by_task.values()]  # a folder has one kind and task
    chead, crows = cost_table([(c.folder.name, c.folder) for c in columns] + explored)
    cost_note = ("Each study's own report's sums: training time is its optimiser steps (every session it ran; pauses "
                 "and curve rollouts excluded: a floor on its wall time), evaluation time its evaluation stages' "
                 "seconds (test and validation); a run reused from an earlier study (same run key) counts as a "
                 "training here and its hours there. A run trained on several machines lists them all, its time "
                 "not split. Times from different machines do not compare.")
    # a task study's decisions informed by a test score: named here too, as its own report names them
    informed = [f"{c.task}: {line}" for c in columns for line in test_informed_lines(c.folder)]
    against = informed_sentence(informed) if informed else ""  # heads both pages
    notes = [f"{c.task}: {c.folder.name}, result files at commit(s) {', '.join(x[:7] for x in c.commits)}"
             for c in columns] + informed
    cells = ("Each cell: success [95% interval] (Wilson over the episodes for one training seed; for several, the "
             "findings' interval over training seeds, t widened to the episodes' where the seeds agree), training "
             "seeds; latency at batch 1 in the fastest exact mode timed (median; 'not timed' where the study timed "
             "nothing)." + (f" Every learned setting: {', '.join(shared)}." if shared else ""))
    timed = sittings_text([(c.task, c.folder) for c in columns])
    cells += f" {timed}" if timed else ""
    md = ["# bcbench report across tasks", "", top, "", *([against, ""] if against else []),
          "## Success and latency per task", "", md_table(head, rows),
          "", cells, "",
          "## Against the goals", "", *goals, "", *([why_head, "", *whys, ""] if whys else []),
          "## The study's findings per task", "",
          "Each task's verdicts under the rules of its own report (paired over its episodes; '-' where a task has "
          "no evidence for a finding).", "", md_table(fhead, frows), "",
          *(["## Demonstrations", "", *demos, ""] if demos else []),
          "## Each task's report and figures", "", *fig_lines, "",
          "## Compute recorded", "", cost_note, "", md_table(chead, crows), "",
          "## Provenance", "", *[f"- {n}" for n in notes], ""]
    md_path = out / "report.md"
    with atomic_path(md_path) as tmp:
        tmp.write_text("\n".join(md) + "\n")
    html_path = out / "report.html"
    css = ("body{font-family:system-ui,sans-serif;max-width:1400px;margin:0 auto 2em;padding:0 1em;color:#222}"
           "table{border-collapse:collapse;font-size:12px}td,th{border:1px solid #ccc;padding:3px 6px;text-align:left}"
           "th{background:#f3f3f3}"
           # the first table grows with every task and setting and has to end in a laptop's first screen (scripts/
           # check_report.py): 11 px and tighter cells keep a table with all 5 tasks' cells filled 120 px above it
           ".grid table{font-size:11px}.grid td,.grid th{padding:2px 4px}.note{font-size:13px;color:#444}")
    body = (f"<h1>bcbench report across tasks</h1><p>{html.escape(top)}</p>"
            + (f"<p>{html.escape(against)}</p>" if against else "")
            + "<h2>Success and latency per task</h2>"
            f"<div class='grid'>{html_table(head, rows)}</div><p class='note'>{html.escape(cells)}</p>"
            "<h2>Against the goals</h2><ul>"
            + "".join(f"<li>{html.escape(x[2:].replace('**', ''))}</li>" for x in goals) + "</ul>"
            + ((f"<p>{html.escape(why_head)}</p><ul>"
                + "".join(f"<li>{html.escape(x[2:].replace('**', ''))}</li>" for x in whys) + "</ul>") if whys else "")
            + f"<h2>The study's findings per task</h2>{html_table(fhead, frows)}"
            + (("<h2>Demonstrations</h2><ul>" + "".join(f"<li>{html.escape(x[2:])}</li>" for x in demos) + "</ul>")
               if demos else "")
            + "<h2>Each task's report and figures</h2><ul>"
            + "".join(f"<li><a href='{_rel(c.folder / 'report' / 'report.html', out)}'>{html.escape(c.task)}</a></li>"
                      for c in columns) + "</ul>"
            + "".join(html_image(t, p, style="max-width:100%") for t, p in figs.items())
            + f"<h2>Compute recorded</h2><p>{html.escape(cost_note)}</p>"
            + html_table(chead, [[x.replace("**", "") for x in r] for r in crows])
            + "<h2>Provenance</h2><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>")
    with atomic_path(html_path) as tmp:
        tmp.write_text(f"<!doctype html><html><head><meta charset='utf-8'><title>bcbench report across tasks</title>"
                       f"<style>{css}</style></head><body>{body}</body></html>\n")
    return {"markdown": str(md_path), "html": str(html_path), "dir": str(out), "warnings": []}


def demo_records(results: Path, spec: dict[str, Any], columns: list[TaskColumn]) -> dict[str, dict[str, Any]]:
    """Task -> its generated store's record (bcbench data generate; scripts/demo_records.py), where across.json
    names their folder and it holds one."""
    if "demos" not in spec:
        return {}
    folder = results / spec["demos"]
    files = {c.task: folder / f"{c.task.split('/')[-1]}.json" for c in columns}
    out = {t: read_json(f) for t, f in files.items() if f.is_file()}
    for t, d in out.items():
        missing = [k for k in ("kept", "attempted", "scripted_success_rate", "episode_length") if k not in d]
        if missing:
            raise BCBenchError(f"{files[t]}: not a demonstration record (no {', '.join(missing)}; "
                               "scripts/demo_records.py writes them)")
    return out


def _demo_lines(records: dict[str, dict[str, Any]], columns: list[TaskColumn]) -> list[str]:
    """Per task the expert's success and the demonstrations kept."""
    if not records:
        return []
    out = []
    for c in columns:
        if c.task not in records:
            out.append(f"- {c.task}: no record of its demonstrations")
            continue
        d = records[c.task]
        out.append(f"- {c.task}: {d['kept']} demonstrations kept of {d['attempted']} scripted episodes (expert "
                   f"success {100 * d['scripted_success_rate']:.1f}%), lengths {d['episode_length']['min']}-"
                   f"{d['episode_length']['max']} steps")
    return out
