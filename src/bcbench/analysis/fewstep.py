"""Few-step generative policies against Diffusion Policy (issue 15's goal), from a study's result rows.

Flow matching on DP's network is sampled with K Euler steps; its claim is DP-level accuracy at a fraction of
DP's time. Per K this compares, on the same episode seeds, flow-K with DP DDPM-100 (the study's reference
setting; paired bootstrap interval of the difference, as the findings do) and puts flow-K's latency beside
DP DDIM-10's (the fast sampler a DP user deploys) in the same inference mode. The goal holds when some
K <= 2 is no worse than DDPM-100 by more than the margin (interval above -margin) at <= 1/5 of DDIM-10's
median latency.

Latency comes from the study's timing stages, unless the study's folder holds a `latency-paired*.json` in the
section's mode (benchmarks/paired_latency.py): settings timed in interleaved rounds, so that a drifting machine does
not change their ratio (a study times each setting in its own block, minutes apart from the others).
A flow-K timed in another sitting than DP DDIM-10 (bcbench.analysis.sittings: e.g. a network timed again alone a
day later) is not set against it, and the goal is then not judged.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bcbench.analysis.findings import (
    Point,
    dp_point,
    held_fixed,
    interleaved_key,
    paired_interval,
    with_interleaved,
)
from bcbench.analysis.sittings import Sitting, sitting_of
from bcbench.errors import BCBenchError
from bcbench.modes import EXACT_MODES
from bcbench.stats import seeds_to_decide
from bcbench.utils.io import read_json

PAIRED_GLOB = "latency-paired*.json"  # one file per inference mode: latency-paired.json, latency-paired-fast.json, ...

GOAL_STEPS = 2  # few-step: at most this many network calls
GOAL_SPEEDUP = 5.0  # at most 1/5 of DP DDIM-10's latency


def _verdict(lo: float, hi: float, m: float) -> str:
    if lo > m:
        return "better by more than the margin"
    if lo > 0:
        return "better"
    if lo > -m:
        return "no worse (within the margin)"
    return "worse" if hi < -m else "inconclusive"


def _ms(p: Point | None) -> str:
    return "-" if p is None or p.latency_ms is None else f"{p.latency_ms:.1f}"


def _score(p: Point | None) -> str:
    return "-" if p is None else f"{p.score:.3f} [{p.ci[0]:.3f}, {p.ci[1]:.3f}]"


def load_paired(study_dir: str | Path) -> dict[str, dict[str, Any]]:
    """Inference mode -> the study folder's interleaved timing in that mode (benchmarks/paired_latency.py), its file
    name under "file"; {} when there is none."""
    out: dict[str, dict[str, Any]] = {}
    for path in sorted(Path(study_dir).glob(PAIRED_GLOB)):
        timing = read_json(path)
        mode = timing.get("mode", "fast")  # the benchmark's default mode
        if mode in out:
            raise BCBenchError(f"{path}: a second interleaved timing in mode {mode!r} (the first: "
                               f"{out[mode]['file']}); keep one per mode")
        out[mode] = {**timing, "file": path.name}
    return out


def fewstep_lines(points: list[Point], margin: float, mode: str = "fast", paired: dict[str, Any] | None = None,
                  sittings: list[Sitting] | None = None) -> list[str]:
    """Markdown lines: a table row per flow K and the goal's verdict; [] when there is no flow or no DP DDPM-100.
    `points` carry their latency in `mode` (bcbench.analysis.findings.points_from_rows); `paired` (load_paired), when
    given and timed in the same mode, replaces the flow and DDIM-10 latencies. With `sittings` (the folder's timing
    sittings), a flow-K timed in another sitting than DDIM-10 gets no share of it."""
    paired = paired if paired is not None and paired.get("mode") == mode else None
    timed = with_interleaved(points, paired)
    flows = sorted((p for p in timed if p.policy == "flow" and p.variant.startswith("euler")),
                   key=lambda p: int(p.variant.removeprefix("euler")))
    ref, ddim10 = dp_point(points, "ddpm", 100), dp_point(timed, "ddim", 10)
    if not flows or ref is None:
        return []
    base_ms = ddim10.latency_ms if ddim10 is not None else None  # the goal's yardstick
    # interleaved rounds are one run by design
    base_sitting = None if paired or ddim10 is None else sitting_of(ddim10.timed_at, sittings or [])
    source = (f"timed in {paired['rounds']} interleaved rounds ({paired.get('file', 'latency-paired')}, "
              f"{paired['threads']} threads)"
              if paired else "timed by the study's stages")
    out = ["## Few-step generative policy against Diffusion Policy", "",
           f"Flow matching on DP's network with K Euler steps, against DP DDPM-100 on the same seeds (paired "
           f"interval of the difference; margin {margin}) and DP DDIM-K; latency: median of one call in the "
           f"'{mode}' mode, {source}, as a share of DP DDIM-10's ({_ms(ddim10)} ms). DP DDPM-100: {_score(ref)}. "
           "Over several training seeds an inconclusive verdict says how many seeds would decide it if its estimate "
           "and the spread of its seeds held (a projection, not a result).",
           "",
           "| flow K | flow score | DP DDIM-K | flow-K - DP DDPM-100 (paired) | verdict | flow ms | / DDIM-10 |",
           "|---|---|---|---|---|---|---|"]
    met, apart, undecided = [], [], []
    for p in flows:
        k = int(p.variant.removeprefix("euler"))
        d = paired_interval(p, [ref])
        est, lo, hi, n = d.est, d.lo, d.hi, d.n
        verdict = _verdict(lo, hi, margin)
        if verdict == "inconclusive" and d.k > 1 and d.within_var is not None:  # a projection for planning
            need = seeds_to_decide(list(d.per_seed), d.within_var, [-margin])
            verdict += f" (about {need} training seeds would decide it)" if need else " (> 50 training seeds)"
        share = p.latency_ms / base_ms if p.latency_ms is not None and base_ms else None
        sitting = None if paired else sitting_of(p.timed_at, sittings or [])
        if share is not None and None not in (sitting, base_sitting) and sitting != base_sitting:
            share = None  # timed hours apart from DDIM-10: the machine's speed is not the same
            apart.append(k)
            if k <= GOAL_STEPS and lo > -margin:
                undecided.append(k)  # the score holds; its speed-up is not measured in one sitting
        seeds = f"{n} seeds" + ("" if d.k == 1 else f" x {d.k} training seeds")
        seeds += "".join(f"; {who}'s one training seed held fixed" for who, q in (("flow", p), ("DP", ref))
                         if d.k > 1 and held_fixed(q))
        out.append(f"| {k} | {_score(p)} | {_score(dp_point(points, 'ddim', k))} | "
                   f"{est:+.3f} [{lo:+.3f}, {hi:+.3f}] ({seeds}) | {verdict} | {_ms(p)} | "
                   f"{('- (another sitting)' if k in apart else '-') if share is None else f'{share:.2f}'} |")
        if k <= GOAL_STEPS and lo > -margin and share is not None and share <= 1 / GOAL_SPEEDUP:
            met.append(k)
    goal = (f"met at K = {', '.join(map(str, met))}" if met else
            f"not judged (flow K = {', '.join(map(str, undecided))} and DP DDIM-10 timed in different sittings)"
            if undecided else "not met" if base_ms else "not judged (no latency for DP DDIM-10)")
    out += ["", f"Goal (K <= {GOAL_STEPS} no worse than DDPM-100 by more than the margin, at <= 1/{GOAL_SPEEDUP:.0f} "
            f"of DDIM-10's latency): **{goal}**.", ""]
    return out


def one_interleaved_run(paired: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Mode -> timing, of the folder's interleaved timings (latency-paired*.json) that were taken in the same rounds
    (one `run_id`, benchmarks/paired_latency.py with several --mode): comparing modes' times across runs would let a
    drifting machine pick the fastest. Files without a run_id (single-mode runs) are not used here."""
    ids = [t["run_id"] for t in paired.values() if t.get("run_id")]
    anchor = (paired.get("reference") or {}).get("run_id") or (ids[-1] if ids else None)
    return {m: t for m, t in paired.items() if anchor and t.get("run_id") == anchor}


def interleaved_medians(run: dict[str, dict[str, Any]] | None, policy: str, variant: str) -> dict[str, float]:
    """Mode -> the median ms that an interleaved run (one_interleaved_run) timed for this setting, in the exact
    modes it timed it in."""
    key = interleaved_key(policy, variant)
    return {m: float(t["median_ms"][key]) for m, t in (run or {}).items()
            if m in EXACT_MODES and key in t.get("median_ms", {})}
