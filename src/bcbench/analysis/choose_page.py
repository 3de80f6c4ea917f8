"""The page `bcbench choose` writes (choose.md, choose.html, fig5_this_machine.png, choose.json): the answer in its
first line, the table under it, then this machine's Figure 5 (committed scores against latency measured here), the
chosen policy's rollout, and how every number was made. Reads the rows bcbench.analysis.choose built; no torch.
"""

from __future__ import annotations

import base64
import html
import os
from pathlib import Path
from typing import Any

from bcbench.analysis.accuracy_latency import place_labels
from bcbench.analysis.choose import choice_header, choice_rows, rank, sweep_sources
from bcbench.analysis.figures import COLOURS, save_png
from bcbench.utils.io import atomic_path, write_json

CSS = ("body{font-family:system-ui,sans-serif;max-width:1400px;margin:0 auto 2em;padding:0 1em;color:#222}"
       "h1{font-size:1.4em;margin:.4em 0 .2em}h2{font-size:1.15em;margin:.6em 0 .3em}"
       "p.answer{font-size:1.05em;background:#eef6ee;border-left:4px solid #176b2c;padding:.4em .6em}"
       "table{border-collapse:collapse;font-size:12px}td,th{border:1px solid #ccc;padding:3px 6px;text-align:left}"
       "th{background:#f3f3f3}tr.chosen td{font-weight:600}img,video{max-width:100%;border:1px solid #eee}"
       "img.fig{max-height:60vh;width:auto}ol,ul{font-size:13px}")


def figure(rows: list[dict[str, Any]], rate_hz: float, chosen: str | None, path: Path) -> Path | None:
    """Figure 5 for this machine: each policy's committed score (a live score, hollow, for one from outside
    models/) against its median call here in its fastest exact mode, log scale; the rate's one-step budget."""
    import matplotlib.pyplot as plt

    pts = [r for r in rows if r.get("fastest") and (r.get("committed") or r.get("live"))]
    if not pts:
        return None
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    labels: list[tuple[float, float, str, str]] = []
    markers: list[tuple[float, float, float]] = []
    for r in pts:
        est = r.get("committed") or r["live"]["mean_score"]
        x, (lo, hi) = r["fastest"]["median_ms"], est["ci95"]
        c = COLOURS.get(r.get("policy", ""), "k")
        hollow = r.get("live_only")
        ax.errorbar([x], [est["value"]], yerr=[[est["value"] - lo], [hi - est["value"]]], fmt="*" if
                    r["label"] == chosen else "o", ms=14 if r["label"] == chosen else 6, color=c,
                    mfc="white" if hollow else c, capsize=2, lw=1)
        labels.append((x, est["value"], r["label"] + (" (live)" if hollow else ""), c))
        markers.append((x, est["value"], 7 if r["label"] == chosen else 3))
    budget = 1e3 / rate_hz
    ax.axvline(budget, ls="--", lw=1, color="k", alpha=0.5)
    ax.text(budget * 0.95, 0.02, f"one step at {rate_hz:g} Hz ({budget:.0f} ms): d = 1 below", rotation=90,
            va="bottom", ha="right", fontsize=7, alpha=0.7, transform=ax.get_xaxis_transform())
    ax.set_xscale("log")
    ax.set_xlabel("median call at batch 1, fastest exact mode, measured on this machine (ms, log)")
    ax.set_ylabel("committed score, sync (95% CI)")
    ax.set_ylim(0, 1.05)
    ax.grid(alpha=0.3)
    place_labels(ax, labels, fontsize=7, markers=markers)  # no label over another (the report's Figure 5 way)
    return save_png(fig, path)


def _md_table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(c.replace("|", "/") for c in r) + " |" for r in rows)]


def _html_table(header: list[str], rows: list[list[str]], chosen: str | None) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(f"<tr{' class=chosen' if r[0] == chosen else ''}>" + "".join(f"<td>{html.escape(c)}</td>"
                                                                                for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def method_notes(record: dict[str, Any]) -> list[str]:
    """How every number on the page was made, one sentence each."""
    t, hw, rate = record["timing"], record["hardware"], record["rate_hz"]
    busy = t.get("cpu_contention") or {}
    return [
        f"Machine: {hw['cpu_model']} ({hw.get('cpu_count')} cores; ISA flags {', '.join(hw.get('cpu_flags') or [])}),"
        f" {t['threads']} torch threads; torch {record['versions'].get('torch')}, commit {record.get('git_commit')}.",
        f"Timing: every policy in each exact mode it runs in here (torch fast, OpenVINO fp32, ONNX Runtime fp32; an "
        f"outside policy as given), batch 1, in {t['rounds']} interleaved rounds of {t['calls_per_round']} calls "
        f"after {t['warm_calls']} warm-up calls each; median and p99 (from >= 100 calls, else the maximum, "
        f"labelled). The fastest mode is what `--backend auto` picks. Other processes used "
        f"{busy.get('other_cpus', 0):.2f} CPUs meanwhile" + (" (not a quiet machine: times are noisy)."
                                                             if busy.get("other_cpus", 0) > 0.1 else "."),
        "x floor: the median against this call's floor here (weights read and FLOPs against the machine's measured "
        "read bandwidth and matrix-product throughput; bcbench.evaluation.floor). Below 1x the weights fit in the "
        "CPU's cache, where the byte term over-counts memory traffic: a rough bound only.",
        f"Delay: d = ceil(tail latency x {rate:g} Hz), at least 1, from the slow calls (p99), since a control loop "
        "must meet its deadline on those too. The committed sweeps count delay in Push-T's 0.1 s steps; at another "
        "rate the score at d reads them as holding in control steps (as Diffusion Policy's Fig. 6 counts delay).",
        "Score at d: from the committed 100-episode real-time sweep of the same weights (async execution) at that "
        "d; naive at the default horizon unless another committed strategy or horizon at that d beats it by its "
        "paired 95% interval. Policies are ranked on it; one with no committed sweep at its d, or scored live only, "
        "is listed and not ranked.",
        f"Re-scored here: the first {record['episodes']} test episodes (seeds from 100000) run live in the committed "
        "evaluation's own setting (sampler, steps, torch fast, seed 0) and paired with the committed per-episode "
        "scores: 'reproduces' when equal within 1e-3 (floating point: another CPU or batch size rounds differently), "
        "else by how much they differ.",
    ]


def write_page(record: dict[str, Any], out: Path) -> dict[str, str]:
    """choose.json, fig5_this_machine.png, choose.md and choose.html in `out`, each written atomically."""
    rows, rate, pick = record["rows"], record["rate_hz"], record["choice"]
    sources = sweep_sources(rows)
    header, table = choice_header(rate), choice_rows(rows, sources)
    fig = figure(rows, rate, pick["chosen"], out / "fig5_this_machine.png")
    write_json(out / "choose.json", record)
    root = Path(record.get("root") or ".")
    cited = [f"[{n}] {_rel(f, root)}" for f, n in sources.items()]
    video = record.get("video")
    video_rel = os.path.relpath(video, out) if video else None
    notes = method_notes(record)
    ranked = {r["label"] for r in rank(rows)[0]}
    unranked = [r["label"] for r in rows if r["label"] not in ranked]
    basis = ("" if pick["basis"] == "realtime" else " Nothing is swept at these delays: ranked on the committed "
             "sync score instead.") + (f" Not ranked: {', '.join(unranked)}." if unranked else "")
    md = ["# Which policy for my control loop, on this machine", "", f"**{pick['line']}.**{basis}", "",
          *_md_table(header, table), "", "Sweeps cited: " + "; ".join(cited) if cited else "No sweep cited.", ""]
    if fig:
        md += ["## Figure 5 on this machine", "", f"![Figure 5 on this machine]({fig.name})", ""]
    if video_rel:
        md += ["## The chosen policy", "",
               f"Rollout (test seed 100000, run as recommended): [{video_rel}]({video_rel})", ""]
    md += ["## How the numbers were made", "", *[f"- {n}" for n in notes], ""]
    with atomic_path(out / "choose.md") as tmp:
        tmp.write_text("\n".join(md) + "\n")
    img = (f"<h2>Figure 5 on this machine</h2><img class='fig' alt='Figure 5 on this machine' "
           f"src='data:image/png;base64,{base64.b64encode(fig.read_bytes()).decode()}'>" if fig else "")
    vid = (f"<h2>The chosen policy</h2><p>Rollout, test seed 100000, run as recommended: "
           f"<a href='{html.escape(video_rel)}'>{html.escape(video_rel)}</a></p>"
           f"<video controls width='384' src='{html.escape(video_rel)}'></video>" if video_rel else "")
    page = (f"<!doctype html><html><head><meta charset='utf-8'><meta name='viewport' "
            f"content='width=device-width, initial-scale=1'><title>bcbench choose</title><style>{CSS}</style></head>"
            f"<body><h1>Which policy for my control loop, on this machine</h1><p class='answer'><b>"
            f"{html.escape(pick['line'])}.</b>{html.escape(basis)}</p>{_html_table(header, table, pick['chosen'])}"
            f"<p style='font-size:12px'>{html.escape('Sweeps cited: ' + '; '.join(cited))}</p>{img}{vid}"
            "<h2>How the numbers were made</h2><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes)
            + "</ul></body></html>\n")
    with atomic_path(out / "choose.html") as tmp:
        tmp.write_text(page)
    return {"markdown": str(out / "choose.md"), "html": str(out / "choose.html"), "json": str(out / "choose.json")}


def _rel(path: str, root: Path) -> str:
    p = Path(path)
    try:
        return str(p.resolve().relative_to(root.resolve()))
    except ValueError:
        return str(p)


def console_table(record: dict[str, Any]) -> str:
    """The table as printed: the answer, then one aligned row per policy."""
    rows, rate = record["rows"], record["rate_hz"]
    header, table = choice_header(rate), choice_rows(rows, sweep_sources(rows))
    widths = [max(len(h), *(len(r[i]) for r in table)) for i, h in enumerate(header)]
    lines = [record["choice"]["line"], "", "  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in table]
    return "\n".join(lines)
