"""The study's figures from result rows (Fig. 5 is in accuracy_latency.py): Fig. 3 (DP vs denoising
steps), Fig. 4 (DDPM-cosine, DDIM-cosine, DDIM-linear over steps), and the latency bar chart."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt

from bcbench.analysis.realtime import delay_curve, step_rate, strategy_of
from bcbench.utils.io import atomic_path


def budgets(rate_hz: float = 10.0, horizons: tuple[int, ...] | list[int] = (8,)) -> tuple[tuple[float, str], ...]:
    """The real-time budget lines of a task: one control step at its rate (a policy re-planning every step answers
    within it) and, per action horizon k the figure's runs execute, k steps (re-planning every k steps). Push-T's
    10 Hz and 8 by default; MetaWorld's 80 Hz and 3 give 12.5 and 37.5 ms."""
    step = 1e3 / rate_hz
    out = [(step, f"{rate_hz:g} Hz, re-plan every step ({step:.3g} ms)")]
    out += [(k * step, f"{rate_hz:g} Hz, re-plan every {k} steps ({k * step:.3g} ms)") for k in sorted(set(horizons))
            if k > 1]
    return tuple(out)


def row_budgets(rows: list[Any]) -> tuple[tuple[float, str], ...]:
    """The budget lines for a figure of result rows: their task's control rate and their trained runs' action
    horizons (a baseline's configured horizon is not one it was trained to execute; with no trained run, every
    row's; with none recorded, Push-T's 8 on Push-T, else the one-step line only). Rows of several known rates (never
    one task's), or of none, get no lines rather than another task's."""
    rates = sorted({r.control_hz for r in rows if r.control_hz})
    horizons = ({r.action_horizon for r in rows if r.train_seed is not None and r.action_horizon}
                or {r.action_horizon for r in rows if r.action_horizon})
    pusht = all(getattr(r, "task", "pusht") == "pusht" for r in rows)
    return budgets(rates[0], sorted(horizons) or ([8] if pusht else [])) if len(rates) == 1 else ()


def _sweep_results(by_policy: dict[str, dict[str, dict[str, Any]]]) -> list[dict[str, Any]]:
    return [r for s in by_policy.values() for r in s.values() if isinstance(r, dict)]


def sweep_budgets(by_policy: dict[str, dict[str, dict[str, Any]]]) -> tuple[tuple[float, str], ...]:
    """The budget lines for real-time sweeps (label -> {setting: evaluation}): their task's step rate
    (`analysis.realtime.step_rate`) and the executed horizons their policies were configured with."""
    results = _sweep_results(by_policy)
    rate, task = step_rate(results)
    horizons = {((r.get("policy") or {}).get("config") or {}).get("action_horizon") for r in results} - {None}
    return budgets(rate, sorted(horizons) or ([8] if task == "Push-T" else []))


def score_word(rows: Any) -> str:
    """What a score axis shows: Push-T's 'mean score' (coverage), or the 'success rate' of a task scored 1/0."""
    return "mean score" if all(getattr(r, "task", "pusht") == "pusht" for r in rows) else "success rate"


COLOURS = {"cnn_mlp": "tab:blue", "resnet50": "tab:orange", "bet": "tab:purple", "bct": "tab:green",
           "diffusion": "tab:red", "flow": "tab:pink", "random": "tab:gray", "scripted": "tab:brown"}

# A policy's second configuration in one report (DP with linear betas beside cosine) takes its own colour, so the
# two are told apart without reading the markers; a third keeps the second's colour and takes the next marker.
SECOND_COLOURS = {"diffusion": "tab:cyan", "flow": "tab:olive", "bct": "darkgreen", "resnet50": "saddlebrown",
                  "cnn_mlp": "navy", "bet": "indigo"}

MARKERS, LINES = ("o", "s", "^", "D"), ("-", "--", ":", "-.")


def nth_of_policy(rows: list[Any]) -> dict[str, int]:
    """label -> 0, 1, ...: the how-manieth configuration of its policy (DP cosine 0, DP linear 1): its colour
    (`colour`), marker and line style."""
    seen: dict[str, list[str]] = {}
    for r in rows:
        labels = seen.setdefault(r.policy, [])
        if r.label not in labels:
            labels.append(r.label)
    return {label: i for labels in seen.values() for i, label in enumerate(labels)}


def colour(policy: str, nth: int) -> str:
    """The colour of a policy's nth configuration (0: its colour in every other figure)."""
    return COLOURS.get(policy, "k") if nth == 0 else SECOND_COLOURS.get(policy, COLOURS.get(policy, "k"))


def save_png(fig: Any, path: Path) -> Path:
    fig.tight_layout()  # keeps a right-hand panel's axis label off its neighbour
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def drop_undrawn(paths: Iterable[Path], drawn: Iterable[Path | None]) -> None:
    """Remove each of a report's figure files that this build did not draw: a report rebuilt in place must not keep
    an earlier drawing beside text that no longer shows it (both the study report and the report across tasks)."""
    for p in set(paths) - set(drawn):  # a None (nothing drawn) matches no path
        p.unlink(missing_ok=True)


def budget_lines(ax: Any, lines: tuple[tuple[float, str], ...], vertical: bool = True) -> None:
    for ms, label in lines:
        (ax.axvline if vertical else ax.axhline)(ms, ls="--", lw=1, color="k", alpha=0.5)
        if vertical:
            # at the foot of the line: the points (good scores) crowd the top of these figures
            ax.text(ms * 0.93, 0.02, label, rotation=90, va="bottom", ha="right", fontsize=7, alpha=0.7,
                    transform=ax.get_xaxis_transform())


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
    ax.set_ylabel(f"{score_word(rows)} (95% CI)")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(fontsize=7)
    ax2.set_yscale("log")
    ax2.set_ylabel(f"inference time per call (ms, {mode}, median)")
    fig.suptitle("Generative policies against sampling steps (the study's Fig. 3)")
    return save_png(fig, path)


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
    ax.set_ylabel(f"{score_word(rows)} (95% CI)")
    ax.set_ylim(0, 1.05)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)  # outside the data
    ax.set_title("Samplers and beta schedules (the study's Fig. 4)")
    return save_png(fig, path)


def latency_bars(records: list[dict[str, Any]], path: Path, title: str,
                 lines: tuple[tuple[float, str], ...]) -> Path | None:
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
    budget_lines(ax, lines=lines)
    ax.set_xlabel("median latency per call, batch 1 (ms, log scale)")
    ax.set_title(title)
    ax.grid(alpha=0.3, axis="x", which="both")
    return save_png(fig, path)


def learning_curves(rows: list[Any], path: Path) -> Path | None:
    """Rollout score (validation seeds) and validation loss against training samples, one line per trained run."""
    runs: dict[str, Any] = {}
    for r in rows:  # one curve per training run (its variants share it)
        if r.curve is not None and (r.curve.score or r.curve.val_loss):
            runs.setdefault(r.key.split(":")[0], r)
    if not runs:
        return None
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    nth = nth_of_policy(list(runs.values()))
    shared = Counter(r.label for r in runs.values())  # several training seeds of one setting: name each seed
    for r in runs.values():
        c, ls = r.curve, LINES[nth[r.label] % len(LINES)]
        tint = colour(r.policy, nth[r.label])
        mark = ("" if shared[r.label] == 1 else f" seed {r.train_seed}") + ("" if r.converged else " (not converged)")
        if c.score:
            ax.plot(c.samples, c.score, ls=ls, marker="o", ms=3, color=tint, label=f"{r.label}{mark}")
            ax.fill_between(c.samples, c.lo, c.hi, color=tint, alpha=0.12)
        if c.val_loss:
            ax2.plot(c.val_samples, c.val_loss, ls=ls, color=tint, label=r.label)
    if _score_axis(ax, "training samples", f"{score_word(runs.values())} on validation seeds (95% CI)", legend=False):
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
    return save_png(fig, path)


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
    """Score against delay d (control steps at the task's rate), one colour per policy: async solid, blocking
    dashed. Sweeps of an execution strategy other than naive (their records say which) are left to the strategies'
    figure, one panel per policy, where they stand beside naive async: here they would double the lines, all in one
    colour."""
    fig, ax = plt.subplots(figsize=(10, 4.5))
    plain = {label: results for label, results in by_policy.items() if strategy_of(results) == "naive"} or by_policy
    left, by_policy = len(by_policy) - len(plain), plain
    style_of = _sweep_colours(by_policy)
    for label, results in by_policy.items():
        colour, marker = style_of[label]
        for execution, style in (("async", "-"), ("blocking", "--")):
            pts = delay_curve(results, execution)
            if len(pts) > 1:
                err = [[e["value"] - e["ci95"][0] for _, e in pts], [e["ci95"][1] - e["value"] for _, e in pts]]
                ax.errorbar([d for d, _ in pts], [e["value"] for _, e in pts], yerr=err, capsize=3, marker=marker,
                            ls=style, color=colour, label=f"{label}, {execution}")
    rate = step_rate(_sweep_results(by_policy))[0]
    if _score_axis(ax, f"delay d (control steps of {1 / rate:g} s at {rate:g} Hz; d = 0: sync, the world waits)",
                   legend=False):
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)  # outside the data
    fig.tight_layout()
    ax.set_title("Score under real-time execution" + (f" (naive; {left} strategy sweeps in the strategies' figure)"
                                                      if left else ""))
    return save_png(fig, path)


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
    budget_lines(ax, lines=sweep_budgets(by_policy))  # the sweeps' task's rate and horizons
    _score_axis(ax, "median latency per call on this machine (ms, log scale)")
    ax.set_title("Figure 5, real time: score under async execution at measured latency (hollow: sync)", fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)  # outside the data
    fig.set_size_inches(12, 5.5)
    fig.tight_layout()
    return save_png(fig, path)
