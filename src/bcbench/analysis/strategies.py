"""Execution strategies compared (issue 31): score against delay, one line per strategy, each paired with naive
async on the same episode seeds, their latency cost, and the highest control rate at which each keeps the policy's
sync score. Reads real-time sweep records only (no torch): one record per (policy, strategy), as
`bcbench realtime --strategy ...` and a study's real-time stage write them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from bcbench.analysis.realtime import (
    compare,
    delay_curve,
    highest_safe_rate,
    largest_safe_delay,
    pool_training_seeds,
    pooled_sentence,
    step_rate,
    with_plain_sync,
)
from bcbench.analysis.results import realtime_records, sweep_label
from bcbench.protocol import delay_setting, policy_label
from bcbench.utils.io import atomic_path

STYLE = {"naive": ("k", "o", "--"), "rtc": ("C3", "s", "-"), "bid": ("C2", "^", "-"), "ensemble": ("C0", "D", "-"),
         "prefix": ("C1", "v", "-"), "correction": ("C4", "P", "-")}
TABLE_DELAYS = (0, 1, 2, 4, 6, 8)


def load_strategy_sweeps(results: str | Path) -> dict[str, dict[str, dict[str, Any]]]:
    """{policy label: {strategy: settings}} from every real-time record under `results` (strategy: naive when the
    record predates strategies); only policies swept with more than one strategy. Sweeps of several training
    seeds are pooled over them (`analysis.realtime.pool_training_seeds`)."""
    found: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for f, data in realtime_records(results):
        variant = data.get("study", {}).get("variant") or {}
        kind = variant.get("strategy") or "naive"
        base = policy_label(sweep_label(f, data), kind)  # one policy, whichever strategy it ran
        shown = kind + (" (J = I)" if variant.get("rtc_jacobian") is False else "")  # RTC's form when not the paper's
        found.setdefault(base, {}).setdefault(shown, []).append(data["settings"])
    return {k: {kind: pool_training_seeds(s) for kind, s in v.items()} for k, v in found.items()
            if len(v) > 1 and "naive" in v}


def versus_naive(sweeps: dict[str, dict[str, Any]], kind: str, name: str) -> tuple[float, float, float, int] | None:
    """A strategy's score minus naive's in the same setting, paired over shared episode seeds, 95% interval."""
    a, b = sweeps[kind].get(name), sweeps["naive"].get(name)
    return compare(a, b) if a and b else None


def measured_ms(settings: dict[str, Any], execution: str = "async") -> float | None:
    """The median measured call time of a sweep's measured setting (the strategy's compute included)."""
    src = settings.get(f"realtime-{execution}-measured", {}).get("summary", {}).get("latency_source", {})
    return src.get("median_ms")


def keeps_sync_rate(sweeps: dict[str, dict[str, Any]], kind: str, margin: float, execution: str = "async"
                    ) -> tuple[int | None, float | None]:
    """(largest safe d, highest control rate in Hz) at which the strategy stays within the margin of the policy's
    plain sync score (naive's d = 0), given its own measured latency."""
    settings = with_plain_sync(sweeps[kind], sweeps["naive"])
    safe = largest_safe_delay(settings, execution, margin)
    ms = measured_ms(sweeps[kind], execution)
    return safe, (highest_safe_rate(safe, ms) if ms else None)


def strategy_table(by_policy: dict[str, dict[str, dict[str, Any]]], margin: float, execution: str = "async"
                   ) -> list[str]:
    """Markdown: policy x strategy rows, score [95%] at d = 0, 1, 2, 4, 6, 8 with the paired difference to naive,
    the measured ms per call and the highest control rate that keeps the sync score."""
    head = ["policy", "strategy", *[f"d = {d}" for d in TABLE_DELAYS], "ms / call (measured)", "keeps sync up to"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, sweeps in by_policy.items():
        for kind in sorted(sweeps, key=lambda k: (k != "naive", k)):
            cells = []
            for d in TABLE_DELAYS:
                r = sweeps[kind].get(delay_setting(execution, d))
                if r is None:
                    cells.append("")
                    continue
                e = r["summary"]["mean_score"]
                cell = f"{e['value']:.3f} [{e['ci95'][0]:.2f}, {e['ci95'][1]:.2f}]"
                vs = versus_naive(sweeps, kind, delay_setting(execution, d)) if kind != "naive" else None
                cells.append(cell + (f"<br>{vs[0]:+.3f} [{vs[1]:+.2f}, {vs[2]:+.2f}]" if vs else ""))
            ms = measured_ms(sweeps[kind], execution)
            safe, rate = keeps_sync_rate(sweeps, kind, margin, execution)
            keeps = ("" if safe is None else "none shown: no delay swept is shown within the margin" if safe == 0
                     else f"d = {safe}" + (f", {rate:.1f} Hz" if rate is not None else ""))
            lines.append(f"| {label} | {kind} | " + " | ".join(cells) + f" | {'' if ms is None else f'{ms:.0f}'} | "
                         f"{keeps} |")
    return lines


def strategy_figure(by_policy: dict[str, dict[str, dict[str, Any]]], path: Path, execution: str = "async"
                    ) -> Path | None:
    """Score against delay, one panel per policy, one line per strategy (95% intervals); None: nothing to draw."""
    if not by_policy:
        return None
    rate, task = step_rate(r for sweeps in by_policy.values() for s in sweeps.values() for r in s.values())
    cols = min(4, len(by_policy))  # a grid, not one row: seven policies in a row are too wide to read
    rows = -(-len(by_policy) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.4 * cols + 2, 3.6 * rows), squeeze=False, sharey=True)
    for ax in axes.flat[len(by_policy):]:
        ax.set_visible(False)
    for ax, (label, sweeps) in zip(axes.flat, by_policy.items(), strict=False):
        for kind, settings in sweeps.items():
            pts = delay_curve(settings, execution)
            colour, marker, ls = STYLE.get(kind.split(" ")[0], ("C7", "x", "-"))
            err = [[e["value"] - e["ci95"][0] for _, e in pts], [e["ci95"][1] - e["value"] for _, e in pts]]
            ax.errorbar([d for d, _ in pts], [e["value"] for _, e in pts], yerr=err, capsize=3, marker=marker,
                        ls=ls, color=colour, label=kind)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel(f"delay d ({execution}; control steps of {1 / rate:g} s)")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
    for row in axes:
        row[0].set_ylabel(f"{'mean score' if task == 'Push-T' else 'success rate'} (95% interval)")
    handles: dict[str, Any] = {}  # every strategy of every panel, once
    for ax in axes.flat:
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(name, handle)
    axes[0][-1].legend(handles.values(), handles.keys(), loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8,
                       title="strategy")  # outside the data
    fig.suptitle("Execution strategies under latency: score against delay", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def strategy_lines(by_policy: dict[str, dict[str, dict[str, Any]]], margin: float) -> list[str]:
    """The report's section: what the table shows and how to read it."""
    if not by_policy:
        return []
    return ["## Execution strategies under latency", "",
            " ".join(filter(None, [
                "Async execution at delay d (d = 0: sync, every strategy included), 95% intervals; under each score "
                "the strategy's difference to naive async in the same setting, paired over episode seeds. "
                f"'Keeps sync up to': the largest d (and, at the strategy's measured call time, the highest control "
                f"rate) whose score stays within {margin} of the policy's plain sync score (paired).",
                pooled_sentence({f"{label} {kind}": s for label, sw in by_policy.items() for kind, s in sw.items()})])),
            "", *strategy_table(by_policy, margin), ""]
