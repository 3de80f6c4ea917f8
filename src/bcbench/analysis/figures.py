"""The study's figures from result rows: Fig. 5 (accuracy vs inference time), Fig. 3 (DP vs denoising
steps), Fig. 4 (DDPM-cosine, DDIM-cosine, DDIM-linear over steps), and the latency bar chart."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt

from bcbench.analysis.fewstep import interleaved_medians
from bcbench.analysis.findings import interleaved_key
from bcbench.analysis.realtime import delay_curve
from bcbench.reference import STUDY_REFERENCE
from bcbench.utils.io import atomic_path

BUDGETS_MS = ((100.0, "10 Hz, re-plan every step (100 ms)"), (800.0, "10 Hz, re-plan every 8 steps (800 ms)"))
COLOURS = {"cnn_mlp": "tab:blue", "resnet50": "tab:orange", "bet": "tab:purple", "bct": "tab:green",
           "diffusion": "tab:red", "flow": "tab:pink", "random": "tab:gray", "scripted": "tab:brown"}


MARKERS, LINES = ("o", "s", "^", "D"), ("-", "--", ":", "-.")


def _nth_of_policy(rows: list[Any]) -> dict[str, int]:
    """label -> 0, 1, ...: the how-manieth run of its policy (DP cosine and DP linear share a colour, not a
    marker or line style)."""
    seen: dict[str, list[str]] = {}
    for r in rows:
        labels = seen.setdefault(r.policy, [])
        if r.label not in labels:
            labels.append(r.label)
    return {label: i for labels in seen.values() for i, label in enumerate(labels)}


def _save(fig: Any, path: Path) -> Path:
    fig.tight_layout()  # keeps a right-hand panel's axis label off its neighbour
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def _budget_lines(ax: Any, vertical: bool = True) -> None:
    for ms, label in BUDGETS_MS:
        (ax.axvline if vertical else ax.axhline)(ms, ls="--", lw=1, color="k", alpha=0.5)
        if vertical:
            # at the foot of the line: the points (good scores) crowd the top of these figures
            ax.text(ms * 0.93, 0.02, label, rotation=90, va="bottom", ha="right", fontsize=7, alpha=0.7,
                    transform=ax.get_xaxis_transform())


def figure5(rows: list[Any], path: Path, mode: str = "reference", timing: dict[str, Any] | None = None,
            run: dict[str, dict[str, Any]] | None = None) -> Path | None:
    """Mean score vs latency per call (log x), marker area by parameters, labels in millions, CI error bars.

    `timing` (a `latency-paired*.json` in `mode`, benchmarks/paired_latency.py) puts the settings it timed at its
    interleaved medians rather than at their own studies' timings: a report over several studies otherwise places
    side by side times taken hours apart, and this VM's speed moves by tens of percent between hours. `run` (mode ->
    timing, fewstep.one_interleaved_run) gives the arrows' deployed times where it timed the setting."""
    interleaved = (timing or {}).get("median_ms", {})
    times = figure5_times(rows, mode, timing)
    pts = [r for r in rows if r.key in times]
    if not pts:
        return None

    def x(r: Any) -> float:
        return times[r.key]

    fig, ax = plt.subplots(figsize=(9, 5.5))
    legend: dict[str, Any] = {}
    labels: list[tuple[float, float, str]] = []
    markers: list[tuple[float, float, float]] = []  # (x, y, radius in points): labels keep clear of them
    nth = _nth_of_policy(pts)
    for r in pts:
        lo, hi = r.est("mean_score")["ci95"]
        size = 30 + 400 * (r.params / 1e8) ** 0.5
        ax.errorbar(x(r), r.score, yerr=[[r.score - lo], [hi - r.score]], fmt="none",
                    ecolor=COLOURS.get(r.policy, "k"), alpha=0.6, capsize=3)
        dot = ax.scatter(x(r), r.score, s=size, color=COLOURS.get(r.policy, "k"), alpha=0.8,
                         edgecolor="k", lw=0.5, marker=MARKERS[nth[r.label] % len(MARKERS)])
        legend.setdefault(f"{r.label}, {r.params / 1e6:.2f} M", dot)
        for v in r.summary.get("per_seed", []):  # several training seeds: each seed's score, faint, beside the mean
            ax.scatter(x(r), v, s=14, color=COLOURS.get(r.policy, "k"), alpha=0.35, lw=0,
                       marker=MARKERS[nth[r.label] % len(MARKERS)])
        markers.append((x(r), r.score, size ** 0.5 / 2))
        deployed = _deployed(r, x(r), mode, run) if mode == "reference" else None
        if deployed and deployed[1] < 0.95 * x(r):  # an arrow to the deployed (exact) time
            ax.annotate("", (deployed[1], r.score), xytext=(x(r), r.score),
                        arrowprops={"arrowstyle": "->", "color": COLOURS.get(r.policy, "k"), "alpha": 0.6, "lw": 1})
            ax.scatter(deployed[1], r.score, s=0)  # the axis reaches the arrow's tip (annotations do not widen it)
        if r.variant != "default":  # a generative policy's settings: name the setting, the legend names it
            labels.append((x(r), r.score, r.variant.upper().replace("-LEADING", "-L")))
    ax.legend(legend.values(), legend.keys(), fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              markerscale=0.5)  # outside the data
    fig.set_size_inches(12, 6.5)  # room for the labels of Diffusion Policy's many settings

    shown = {r.reference_key for r in pts}
    for key, ref in STUDY_REFERENCE.items():  # the study's own points (A100), hollow, for comparison
        if key in shown and ref.get("score") is not None and ref.get("latency_ms"):
            ax.scatter(ref["latency_ms"], ref["score"], s=60, facecolors="none", edgecolors=COLOURS.get(key, "k"),
                       lw=1.2, marker="D")
            ax.annotate("study (A100)", (ref["latency_ms"], ref["score"]), fontsize=6, xytext=(5, -9),
                        textcoords="offset points", alpha=0.7)
    ax.set_xscale("log")
    _budget_lines(ax)
    source = (f"; {sum(interleaved_key(r.policy, r.variant) in interleaved for r in pts)} of {len(pts)} settings "
              f"timed in {timing['rounds']} interleaved rounds ({timing.get('file', 'latency-paired')})"
              if interleaved else "")
    ax.set_xlabel(f"inference time per call, batch 1 ({mode} mode, median, ms, log scale{source})\narrows: to the "
                  "fastest exact deployed mode; hollow diamonds: the study's numbers")
    ax.set_ylabel("mean score (max coverage / 0.95), 95% CI")
    ax.set_ylim(-0.05, 1.05)
    ax.set_title("Accuracy against inference time (the study's Fig. 5)")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    place_labels(ax, labels, markers=markers)
    return _save(fig, path)


def _deployed(r: Any, at: float, mode: str, run: dict[str, dict[str, Any]] | None) -> tuple[str, float] | None:
    """(mode, ms) of a row's fastest exact deployed mode: from the interleaved run where it timed the setting, else
    its own record's ratio to `mode` applied to where the point stands (`at`)."""
    timed = [(m, ms) for m, ms in interleaved_medians(run, r.policy, r.variant).items() if m != mode]  # not the axis'
    if timed:
        return min(timed, key=lambda t: t[1])
    own = r.deployed_ms()
    return (own[0], own[1] * at / r.latency_ms(mode)) if own and r.latency_ms(mode) else None


def figure5_times(rows: list[Any], mode: str = "reference", timing: dict[str, Any] | None = None
                  ) -> dict[str, float]:
    """Row key -> Figure 5's x: the interleaved median where `timing` timed the setting, else the row's own."""
    interleaved = (timing or {}).get("median_ms", {})
    times = {r.key: interleaved.get(interleaved_key(r.policy, r.variant)) or r.latency_ms(mode) for r in rows}
    return {k: float(v) for k, v in times.items() if v is not None}


DY = (-3, 4, -10, 11, -17, 18, -24, 25, -31)  # label rows above and below a point, nearest first (points)


def place_labels(ax: Any, items: list[tuple[float, float, str]], fontsize: float = 6,
                 markers: list[tuple[float, float, float]] | None = None) -> None:
    """Name points without a label overlapping another label or any marker.

    `markers` are (x, y, radius in points) of every drawn marker. Each label (left to right) takes the first
    free place to the right, then to the left, of its point, a row nearer first (DY); a label that finds no free
    place goes to the last candidate, joined to its point by a thin line so it still names the right one."""
    ax.figure.canvas.draw()  # final limits and log scale: data -> display transform
    pt = ax.figure.dpi / 72  # display units per typographic point
    discs = [(*ax.transData.transform((x, y)), r * pt) for x, y, r in (markers or [])]
    placed = [(dx - r, dy - r, 2 * r, 2 * r) for dx, dy, r in discs]  # markers block labels

    def free(box: tuple[float, float, float, float]) -> bool:
        bx, by, bw, bh = box
        return not any(bx < qx + qw and qx < bx + bw and by < qy + qh and qy < by + bh for qx, qy, qw, qh in placed)

    for x, y, text in sorted(items):
        px, py = ax.transData.transform((x, y))
        r = max((d[2] for d in discs if abs(d[0] - px) < 1e-6 and abs(d[1] - py) < 1e-6), default=2 * pt) / pt
        w, h = 0.6 * fontsize * len(text) * pt, fontsize * pt
        offsets = [(side * (r + 2), dy) for dy in DY for side in (1, -1)]
        offsets += [(side * (r + 2 + k), dy) for k in (15, 30) for dy in DY[:5] for side in (1, -1)]
        boxes = [(px + dx * pt - (w if dx < 0 else 0), py + dy * pt, w, h) for dx, dy in offsets]
        i = next((j for j, b in enumerate(boxes) if free(b)), len(boxes) - 1)
        placed.append(boxes[i])
        dx, dy = offsets[i]
        far = abs(dx) > r + 3 or abs(dy) > r + 4
        ax.annotate(text, (x, y), xytext=(dx, dy + (h / pt) / 2), textcoords="offset points", fontsize=fontsize,
                    ha="right" if dx < 0 else "left", va="center",
                    arrowprops={"arrowstyle": "-", "lw": 0.4, "alpha": 0.5, "shrinkA": 0, "shrinkB": r}
                    if far else None)


def _dp_rows(rows: list[Any], sampler: str, schedule: str, spacing: str | None = None) -> list[Any]:
    """Diffusion Policy rows of one sampler and beta schedule; trailing spacing unless asked otherwise."""
    out = [r for r in rows if r.policy == "diffusion" and r.sampler == sampler
           and (r.beta_schedule or "squaredcos_cap_v2") == schedule and (r.spacing or "leading") == (spacing or
                                                                                                    "trailing")]
    if not out and spacing is None:  # results from before trailing spacing existed
        return _dp_rows(rows, sampler, schedule, "leading")
    return sorted(out, key=lambda r: r.steps)


def _step_series(rows: list[Any]) -> list[tuple[str, list[Any], str]]:
    """(label, rows sorted by steps, line style) for every family evaluated at 2+ step counts."""
    series = [("DP DDPM", _dp_rows(rows, "ddpm", "squaredcos_cap_v2"), "-"),
              ("DP DDIM", _dp_rows(rows, "ddim", "squaredcos_cap_v2"), "-"),
              ("DP DDPM, leading spacing", _dp_rows(rows, "ddpm", "squaredcos_cap_v2", "leading"), ":"),
              ("DP DDIM, leading spacing", _dp_rows(rows, "ddim", "squaredcos_cap_v2", "leading"), ":")]
    for kind in ("euler", "midpoint"):
        series.append((f"flow, {kind}", sorted([r for r in rows if r.policy == "flow" and r.sampler == kind],
                                               key=lambda r: r.steps), "--"))
    seen, out = set(), []
    for label, s, style in series:
        keys = tuple(r.key for r in s)
        if len(s) >= 2 and keys not in seen:  # without trailing results the 'leading' lines would repeat
            seen.add(keys)
            out.append((label, s, style))
    return out


def figure3(rows: list[Any], path: Path, mode: str = "reference") -> Path | None:
    """Score and latency against denoising / integration steps: DP's samplers (and spacings), flow matching."""
    series = _step_series(rows)
    if not series:
        return None
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    for label, s, style in series:
        steps = [r.steps for r in s]
        lo = [r.est("mean_score")["ci95"][0] for r in s]
        hi = [r.est("mean_score")["ci95"][1] for r in s]
        (line,) = ax.plot(steps, [r.score for r in s], style, marker="o", label=label)
        ax.fill_between(steps, lo, hi, alpha=0.12, color=line.get_color())
        lat = [(r.steps, r.latency_ms(mode)) for r in s if r.latency_ms(mode) is not None]
        if lat:
            ax2.plot(*zip(*lat, strict=True), style, marker="o", color=line.get_color(), label=label)
    if not ax2.lines:  # a study exported before its latency stages ran: say so rather than draw empty axes
        ax2.text(0.5, 0.5, f"not timed yet\n(no {mode}-mode latency record)", ha="center", va="center",
                 transform=ax2.transAxes, fontsize=10, alpha=0.7)
    for a in (ax, ax2):
        a.set_xscale("log")
        a.set_xlabel("denoising / integration steps (log scale)")
        a.grid(alpha=0.3, which="both")
    ax.set_ylabel("mean score (95% CI)")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(fontsize=7)
    ax2.set_yscale("log")
    ax2.set_ylabel(f"inference time per call (ms, {mode}, median)")
    fig.suptitle("Generative policies against sampling steps (the study's Fig. 3)")
    return _save(fig, path)


def figure4(rows: list[Any], path: Path) -> Path | None:
    """Mean score over steps for DDPM-cosine, DDIM-cosine and DDIM-linear side by side."""
    series = [("DDPM, cosine betas", _dp_rows(rows, "ddpm", "squaredcos_cap_v2")),
              ("DDIM, cosine betas", _dp_rows(rows, "ddim", "squaredcos_cap_v2")),
              ("DDIM, linear betas", _dp_rows(rows, "ddim", "linear"))]
    series = [(n, s) for n, s in series if s]
    if len(series) < 2:
        return None
    fig, ax = plt.subplots(figsize=(8.5, 4))
    width = 0.8 / len(series)
    all_steps = sorted({r.steps for _, s in series for r in s})
    for i, (name, s) in enumerate(series):
        xs = [all_steps.index(r.steps) + (i - (len(series) - 1) / 2) * width for r in s]
        vals = [r.score for r in s]
        err = [[r.score - r.est("mean_score")["ci95"][0] for r in s],
               [r.est("mean_score")["ci95"][1] - r.score for r in s]]
        k = max(len(r.seed_scores) or 1 for r in s)  # a line of one run next to means over seeds: say which
        seeds = f"mean of {k} training seeds" if k > 1 else "one training seed"
        ax.bar(xs, vals, width, yerr=err, capsize=3, alpha=0.8, label=f"{name}\n({seeds})")
    ax.set_xticks(range(len(all_steps)), [str(k) for k in all_steps])
    ax.set_xlabel("denoising iterations")
    ax.set_ylabel("mean score (95% CI)")
    ax.set_ylim(0, 1.05)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)  # outside the data
    ax.set_title("Samplers and beta schedules (the study's Fig. 4)")
    return _save(fig, path)


def latency_bars(records: list[dict[str, Any]], path: Path, title: str) -> Path | None:
    """Horizontal bars of median latency (log x) per row, with the real-time budget lines."""
    if not records:
        return None
    fig, ax = plt.subplots(figsize=(8, 0.28 * len(records) + 1.5))
    labels = [r["label"] for r in records]
    vals = [r["median_ms"] for r in records]
    colours = [COLOURS.get(r.get("policy", ""), "tab:gray") for r in records]
    ax.barh(range(len(records)), vals, color=colours, alpha=0.8)
    ax.set_yticks(range(len(records)), labels, fontsize=7)
    ax.invert_yaxis()
    ax.set_xscale("log")
    _budget_lines(ax)
    ax.set_xlabel("median latency per call, batch 1 (ms, log scale)")
    ax.set_title(title)
    ax.grid(alpha=0.3, axis="x", which="both")
    return _save(fig, path)


def learning_curves(rows: list[Any], path: Path) -> Path | None:
    """Rollout score (validation seeds) and validation loss against training samples, one line per trained run."""
    runs: dict[str, Any] = {}
    for r in rows:  # one curve per training run (its variants share it)
        if r.curve is not None and (r.curve.score or r.curve.val_loss):
            runs.setdefault(r.key.split(":")[0], r)
    if not runs:
        return None
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    nth = _nth_of_policy(list(runs.values()))
    shared = Counter(r.label for r in runs.values())  # several training seeds of one setting: name each seed
    for r in runs.values():
        c, colour, ls = r.curve, COLOURS.get(r.policy, "k"), LINES[nth[r.label] % len(LINES)]
        mark = ("" if shared[r.label] == 1 else f" seed {r.train_seed}") + ("" if r.converged else " (not converged)")
        if c.score:
            ax.plot(c.samples, c.score, ls=ls, marker="o", ms=3, color=colour, label=f"{r.label}{mark}")
            ax.fill_between(c.samples, c.lo, c.hi, color=colour, alpha=0.12)
        if c.val_loss:
            ax2.plot(c.val_samples, c.val_loss, ls=ls, color=colour, label=r.label)
    if _score_axis(ax, "training samples", "mean score on validation seeds (95% CI)", legend=False):
        # below both panels, outside the data; the validation-loss lines share these colours and styles
        fig.legend(*ax.get_legend_handles_labels(), loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=3,
                   fontsize=7)
    else:
        ax.text(0.5, 0.5, "no rollouts logged while training\n(train with --eval-every)", ha="center",
                transform=ax.transAxes, alpha=0.6)
    ax.set_title("Learning curves: closed-loop score")
    ax2.set_xlabel("training samples")
    ax2.set_ylabel("validation loss (held-out episodes)")
    ax2.set_yscale("log")
    ax2.grid(alpha=0.3, which="both")
    ax2.set_title("Validation loss")
    return _save(fig, path)


def _score_axis(ax: Any, xlabel: str, ylabel: str = "mean score (95% CI)", legend: bool = True) -> bool:
    """Labels, a 0-1 score range, a grid, and a legend when anything is labelled (returned)."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_ylim(-0.05, 1.05)
    ax.grid(alpha=0.3)
    labelled = bool(ax.get_legend_handles_labels()[0])
    if labelled and legend:
        ax.legend(fontsize=7)
    return labelled


def _sweep_colours(by_policy: dict[str, dict[str, dict[str, Any]]]) -> dict[str, tuple[str, str]]:
    """label -> (colour, marker): the policy's colour of every other figure (from the sweep's evaluation records);
    a second sweep of the same policy (another backend) keeps the colour and takes the next marker."""
    out, seen = {}, {}
    for i, (label, results) in enumerate(by_policy.items()):
        name = next(iter(results.values()), {}).get("policy", {}).get("name", "")
        n = seen[name] = seen.get(name, -1) + 1
        out[label] = (COLOURS.get(name, f"C{i % 10}"), MARKERS[n % len(MARKERS)])
    return out


def realtime_figure(by_policy: dict[str, dict[str, dict[str, Any]]], path: Path) -> Path:
    """Score against delay d (control steps of 0.1 s), one colour per policy: async solid, blocking dashed."""
    fig, ax = plt.subplots(figsize=(10, 4.5))
    style_of = _sweep_colours(by_policy)
    for label, results in by_policy.items():
        colour, marker = style_of[label]
        for execution, style in (("async", "-"), ("blocking", "--")):
            pts = delay_curve(results, execution)
            if len(pts) > 1:
                err = [[e["value"] - e["ci95"][0] for _, e in pts], [e["ci95"][1] - e["value"] for _, e in pts]]
                ax.errorbar([d for d, _ in pts], [e["value"] for _, e in pts], yerr=err, capsize=3, marker=marker,
                            ls=style, color=colour, label=f"{label}, {execution}")
    if _score_axis(ax, "delay d (control steps of 0.1 s at 10 Hz; d = 0: sync, the world waits)", legend=False):
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)  # outside the data
    fig.tight_layout()
    ax.set_title("Score under real-time execution")
    return _save(fig, path)


def figure5_realtime(by_policy: dict[str, dict[str, dict[str, Any]]], path: Path) -> Path | None:
    """'Figure 5, real time': each policy's async score at its measured latency on this machine against that
    latency (filled), its sync score at the same latency (hollow, the world waits) joined by the real-time cost."""
    pts, style_of = [], _sweep_colours(by_policy)
    for label, results in by_policy.items():
        rt, sync = results.get("realtime-async-measured"), results.get("realtime-sync")
        if rt and sync:
            ms = rt["summary"]["latency_source"]["median_ms"]
            pts.append((label, style_of[label], ms, rt["summary"]["mean_score"], sync["summary"]["mean_score"]))
    if not pts:
        return None
    fig, ax = plt.subplots(figsize=(9, 5.5))
    for label, (colour, marker), ms, rt, sync in pts:
        ax.plot([ms, ms], [sync["value"], rt["value"]], color=colour, alpha=0.5, lw=1)
        ax.scatter(ms, sync["value"], s=60, facecolor="none", edgecolor=colour, marker=marker)
        ax.errorbar(ms, rt["value"], yerr=[[rt["value"] - rt["ci95"][0]], [rt["ci95"][1] - rt["value"]]],
                    fmt=marker, color=colour, capsize=3, label=f"{label} ({ms:.0f} ms)")
    ax.set_xscale("log")
    _budget_lines(ax)
    _score_axis(ax, "median latency per call on this machine (ms, log scale)")
    ax.set_title("Figure 5, real time: score under async execution at measured latency (hollow: sync)", fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)  # outside the data
    fig.set_size_inches(12, 5.5)
    fig.tight_layout()
    return _save(fig, path)
