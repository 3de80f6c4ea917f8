"""The study's Figure 5, mean score against inference time per call, and its zoom on the generative settings.

A report over several studies has 30 or more settings of Diffusion Policy and flow within a decade of time and
0.2 of score. Their names do not fit beside the points at the size the report opens with, so Figure 5 names only
the settings outside that cluster and draws a dashed box around the cluster. The zoom, full width further down,
names every setting inside the box."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt

from bcbench.analysis.fewstep import interleaved_medians
from bcbench.analysis.figures import (
    COLOURS,
    MARKERS,
    budget_lines,
    colour,
    nth_of_policy,
    row_budgets,
    save_png,
    score_word,
)
from bcbench.analysis.findings import interleaved_key, shared_timing
from bcbench.reference import STUDY_REFERENCE

ZOOM_MIN = 8  # labelled settings: fewer than this fit in the one panel, and there is no zoom
ZOOM_BAND = 0.25  # the zoom holds the labelled settings scoring within this of the best one


@dataclass
class Panel:
    """What one axis of Figure 5 draws: the points, where each stands, how each looks."""

    pts: list[Any]
    times: dict[str, float]  # row key -> x (ms)
    mode: str
    run: dict[str, dict[str, Any]] | None

    def __post_init__(self) -> None:
        self.nth = nth_of_policy(self.pts)
        # row key -> (mode, ms) of its fastest exact deployed mode, where an arrow points (both panels, the box)
        self.tips = {r.key: t for r in self.pts if (t := _deployed(r, self.times[r.key], self.mode, self.run))}

    def style(self, r: Any) -> tuple[str, str]:
        n = self.nth[r.label]
        return colour(r.policy, n), MARKERS[n % len(MARKERS)]

    def draw(self, ax: Any) -> tuple[dict[str, tuple[str, Any]], list[tuple[float, float, float]]]:
        """Every point with its interval, its training seeds (faint) and its arrow to the fastest exact mode.
        Returns label -> (legend text, handle) and each marker's (x, y, radius in points), which labels keep clear
        of."""
        legend: dict[str, tuple[str, Any]] = {}
        markers: list[tuple[float, float, float]] = []
        for r in self.pts:
            x, (c, m) = self.times[r.key], self.style(r)
            lo, hi = r.est("mean_score")["ci95"]
            size = 30 + 400 * (r.params / 1e8) ** 0.5
            ax.errorbar(x, r.score, yerr=[[r.score - lo], [hi - r.score]], fmt="none", ecolor=c, alpha=0.6,
                        capsize=3)
            dot = ax.scatter(x, r.score, s=size, color=c, alpha=0.8, edgecolor="k", lw=0.5, marker=m)
            legend.setdefault(r.label, (f"{r.label}, {r.params / 1e6:.2f} M", dot))
            for v in r.summary.get("per_seed", []):  # several training seeds: each seed's score, faint
                ax.scatter(x, v, s=14, color=c, alpha=0.35, lw=0, marker=m)
            markers.append((x, r.score, size ** 0.5 / 2))
            deployed = self.tips.get(r.key) if self.mode == "reference" else None
            if deployed and deployed[1] < 0.95 * x:  # an arrow to the deployed (exact) time
                ax.annotate("", (deployed[1], r.score), xytext=(x, r.score),
                            arrowprops={"arrowstyle": "->", "color": c, "alpha": 0.6, "lw": 1})
                ax.scatter(deployed[1], r.score, s=0)  # the axis reaches the arrow's tip
        ax.set_xscale("log")
        ax.grid(alpha=0.3, which="both")
        budget_lines(ax, lines=row_budgets(self.pts))  # the task's rate and the runs' action horizons
        return legend, markers

    def label(self, r: Any) -> tuple[float, float, str, str]:
        return self.times[r.key], r.score, r.variant.upper().replace("-LEADING", "-L"), self.style(r)[0]


def zoom_box(panel: Panel) -> tuple[list[Any], tuple[float, float, float, float]] | None:
    """(settings inside, (x0, x1, y0, y1)): the generative settings within ZOOM_BAND of the best one, and a box
    around them (and their arrows' tips); None when fewer than ZOOM_MIN of them crowd there."""
    named = [r for r in panel.pts if r.variant != "default"]
    best = max((r.score for r in named), default=0.0)
    inside = [r for r in named if r.score >= best - ZOOM_BAND]
    if len(inside) < ZOOM_MIN:
        return None
    xs = [panel.times[r.key] for r in inside]
    tips = [panel.tips[r.key][1] for r in inside if r.key in panel.tips]
    ys = [r.score for r in inside]
    return inside, (min(xs + tips) / 1.25, max(xs) * 1.6, min(ys) - 0.04, max(ys) + 0.04)


def score_axis(rows: list[Any]) -> str:
    """What the score axis measures: Push-T's coverage score, or the success rate of a task scored by success."""
    if score_word(rows) == "mean score":
        return "mean score (max coverage / 0.95)"
    return "success rate (success at any step)"


def figure5(rows: list[Any], path: Path, mode: str = "reference", timing: dict[str, Any] | None = None,
            run: dict[str, dict[str, Any]] | None = None, zoom_path: Path | None = None
            ) -> tuple[Path | None, Path | None]:
    """Mean score vs latency per call (log x), marker area by parameters, labels in millions, CI error bars;
    and, where the generative settings crowd, their zoom at `zoom_path` (else None).

    `timing` (a `latency-paired*.json` in `mode`, benchmarks/paired_latency.py) puts the settings it timed at its
    interleaved medians rather than at their own studies' timings: a report over several studies otherwise places
    side by side times taken hours apart, and this VM's speed moves by tens of percent between hours. `run` (mode ->
    timing, fewstep.one_interleaved_run) gives the arrows' deployed times where it timed the setting."""
    times = figure5_times(rows, mode, timing)
    panel = Panel([r for r in rows if r.key in times], times, mode, run)
    if not panel.pts:
        return None, None
    zoom = zoom_box(panel) if zoom_path else None
    inside = {r.key for r in zoom[0]} if zoom else set()
    fig, ax = plt.subplots(figsize=(12, 6.5))  # room for the labels of Diffusion Policy's many settings
    legend, markers = panel.draw(ax)
    _legend(ax, legend.values())
    _study_points(ax, {r.reference_key for r in panel.pts})
    interleaved = (timing or {}).get("median_ms", {})
    shared, file = shared_timing(panel.pts, timing), (timing or {}).get("file", "latency-paired")
    source = (f"; {sum(interleaved_key(r.policy, r.variant) in interleaved for r in panel.pts)} of {len(panel.pts)}"
              f" settings at the medians of {timing['rounds']} interleaved rounds ({file}"
              + (f"; {' and '.join(shared)} share them" if shared else "") + ")" if interleaved else "")
    ax.set_xlabel(f"inference time per call, batch 1 ({mode} mode, median, ms, log scale{source})\narrows: to the "
                  "fastest exact deployed mode; hollow diamonds: the study's numbers"
                  + ("; dashed box: named in the zoom below" if zoom else ""))
    ax.set_ylabel(score_axis(panel.pts) + ", 95% CI")
    ax.set_ylim(-0.05, 1.05)
    ax.set_title("Accuracy against inference time (the study's Fig. 5)")
    if zoom:
        x0, x1, y0, y1 = zoom[1]
        ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ls="--", lw=1, ec="k", alpha=0.6))
    fig.tight_layout()
    place_labels(ax, [panel.label(r) for r in panel.pts if r.variant != "default" and r.key not in inside],
                 markers=markers)
    return save_png(fig, path), (_zoom_figure(panel, zoom, zoom_path) if zoom else None)


def _zoom_figure(panel: Panel, zoom: tuple[list[Any], tuple[float, float, float, float]], path: Path) -> Path:
    """The dashed box of Figure 5 at full width, every setting in it named."""
    inside, (x0, x1, y0, y1) = zoom
    fig, ax = plt.subplots(figsize=(12, 6.5))
    legend, markers = panel.draw(ax)
    seen = {r.label for r in panel.pts if x0 <= panel.times[r.key] <= x1 and y0 <= r.score <= y1}
    _legend(ax, [entry for label, entry in legend.items() if label in seen])  # what the box holds
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xlabel(f"inference time per call, batch 1 ({panel.mode} mode, median, ms, log scale), as in Figure 5\n"
                  "error bars: 95% CI (they reach past this box); faint points: each training seed; arrows: to the "
                  "fastest exact deployed mode")
    ax.set_ylabel(score_axis(panel.pts))
    ax.set_title(f"Figure 5, zoomed: the {len(inside)} generative settings within {ZOOM_BAND} of the best score")
    fig.tight_layout()
    place_labels(ax, [panel.label(r) for r in inside], fontsize=7, markers=markers)
    return save_png(fig, path)


def _legend(ax: Any, entries: Any) -> None:
    """(text, handle) pairs as a legend outside the data."""
    texts, handles = zip(*entries, strict=True) if entries else ((), ())
    ax.legend(handles, texts, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), markerscale=0.5)


def _study_points(ax: Any, shown: set[str]) -> None:
    """The study's own points (A100), hollow, for comparison."""
    for key, ref in STUDY_REFERENCE.items():
        if key in shown and ref.get("score") is not None and ref.get("latency_ms"):
            ax.scatter(ref["latency_ms"], ref["score"], s=60, facecolors="none", edgecolors=COLOURS.get(key, "k"),
                       lw=1.2, marker="D")
            ax.annotate("study (A100)", (ref["latency_ms"], ref["score"]), fontsize=6, xytext=(5, -9),
                        textcoords="offset points", alpha=0.7)


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


def place_labels(ax: Any, items: list[tuple[float, float, str, str]], fontsize: float = 6,
                 markers: list[tuple[float, float, float]] | None = None) -> list[Any]:
    """Name points without a label overlapping another label or any marker; returns the labels (Text).

    `items` are (x, y, text, colour): a label takes its point's colour, so two settings of one name (DDPM5 of two
    configurations) are told apart. `markers` are (x, y, radius in points) of every drawn marker. Each label (left
    to right) takes the first free place to the right, then to the left, of its point, a row nearer first (DY); a
    label that finds no free place goes to the last candidate, joined to its point by a thin line so it still names
    the right one."""
    ax.figure.canvas.draw()  # final limits and log scale: data -> display transform
    pt = ax.figure.dpi / 72  # display units per typographic point
    discs = [(*ax.transData.transform((x, y)), r * pt) for x, y, r in (markers or [])]
    placed = [(dx - r, dy - r, 2 * r, 2 * r) for dx, dy, r in discs]  # markers block labels

    def free(box: tuple[float, float, float, float]) -> bool:
        bx, by, bw, bh = box
        return not any(bx < qx + qw and qx < bx + bw and by < qy + qh and qy < by + bh for qx, qy, qw, qh in placed)

    out = []
    for x, y, text, tint in sorted(items):
        px, py = ax.transData.transform((x, y))
        r = max((d[2] for d in discs if abs(d[0] - px) < 1e-6 and abs(d[1] - py) < 1e-6), default=2 * pt) / pt
        w, h = _extent(ax, text, fontsize)
        offsets = [(side * (r + 2), dy) for dy in DY for side in (1, -1)]
        offsets += [(side * (r + 2 + k), dy) for k in (15, 30) for dy in DY[:5] for side in (1, -1)]
        boxes = [(px + dx * pt - (w if dx < 0 else 0), py + dy * pt, w, h) for dx, dy in offsets]
        i = next((j for j, b in enumerate(boxes) if free(b)), len(boxes) - 1)
        placed.append(boxes[i])
        dx, dy = offsets[i]
        far = abs(dx) > r + 3 or abs(dy) > r + 4
        out.append(ax.annotate(text, (x, y), xytext=(dx, dy + (h / pt) / 2), textcoords="offset points",
                               fontsize=fontsize, ha="right" if dx < 0 else "left", va="center", color=tint,
                               arrowprops={"arrowstyle": "-", "lw": 0.4, "alpha": 0.5, "shrinkA": 0, "shrinkB": r}
                               if far else None))
    return out


def _extent(ax: Any, text: str, fontsize: float) -> tuple[float, float]:
    """(width, height) of `text` as drawn, in display units: measured, since capitals and digits are wider than an
    average character and a guess let labels overlap."""
    probe = ax.text(0, 0, text, fontsize=fontsize)
    box = probe.get_window_extent(ax.figure.canvas.get_renderer())
    probe.remove()
    return box.width, box.height
