"""Convergence that a schedule cannot fake: a run with twice the optimiser steps (same recipe, its schedule sized to
them) must not beat the run it checks by more than the margin, on the same validation episodes (issue 30).

A learning curve flat over its last quarter is not evidence of convergence under a cosine schedule: the rate there
is a few percent of its peak, so the curve flattens by construction. The check instead trains a second run
(`doubles = "LABEL"` in the study file) and compares the two, variant by variant, with a paired two-sided 95%
interval of (twice the steps) minus (the run): converged if the interval lies below +margin, not converged if it
lies above, inconclusive otherwise.

A run is judged once, on all its settings together (`run_verdicts`): the per-episode difference averaged over the
settings where either run works (scores >= POOL_FLOOR), with one interval. Requiring every setting's own interval to
lie below the margin asks too much of 100 episodes: a setting's paired differences have an SD of about 0.23-0.36
(results/cpu-confirm-dpflow), so its interval is +/-0.045-0.070 wide and a run that doubling truly leaves unchanged
passes each setting with probability about 0.3-0.6, and all of four or thirteen rarely. Averaged over the settings
(each samples its own chunks on the same episode seeds, so much of their noise is independent), the SD falls to
0.10-0.12 (DP, 13 settings) and 0.24 (flow, 4): the same question asked once, with the power to answer it. A setting
whose own interval lies wholly above the margin still makes the run not converged, so a gain confined to one sampler
is not averaged away.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

import numpy as np

from bcbench.analysis.results import Row
from bcbench.stats import bootstrap_ci, paired_bootstrap

CONVERGED, NOT_CONVERGED, INCONCLUSIVE = "converged", "not converged", "inconclusive"
NO_CHECK = "no twice-the-steps check yet"  # a run of a study under the seed protocol awaiting its check
# A setting where both runs score below this is left out of a run's pooled difference: a sampler that does not work
# (Diffusion Policy with one denoising step scores about 0.1 either way) says nothing about training, and its zero
# difference would pull the pool towards "converged". Decided by the runs' scores, not by their difference.
POOL_FLOOR = 0.5


@dataclass
class Check:
    run: str  # the checked run's label
    variant: str
    est: float
    lo: float
    hi: float
    n: int
    verdict: str
    train_seed: int = 0  # of the run checked (and of its twice-the-steps run)
    means: tuple[float, float] = (float("nan"), float("nan"))  # the run's and twice the steps' mean scores
    diffs: dict[int, float] = field(default_factory=dict)  # episode seed -> twice the steps minus the run

    def table_row(self) -> str:
        v = "-" if self.variant == "default" else self.variant.upper()
        return (f"| {self.run} | {v} | {self.means[0]:.3f} | {self.means[1]:.3f} | {self.est:+.3f} "
                f"[{self.lo:+.3f}, {self.hi:+.3f}] | {self.n} | **{self.verdict}** |")


def doubling_checks(rows: list[Row], margin: float) -> list[Check]:
    """Every (checked run, variant) that has its twice-the-steps run evaluated on shared episodes."""
    # the checked run of the same training seed (a confirm study trains the preset with several)
    base = {(r.run_label, r.variant, r.train_seed): r for r in rows if r.run_label}
    out = []
    # run, then sampler, then steps as a number (DDIM-2 before DDIM-10): the table's order
    for r in sorted(rows, key=lambda r: (r.doubles or "", r.sampler or r.variant, r.steps or 0, r.variant)):
        b = base.get((r.doubles, r.variant, r.train_seed)) if r.doubles else None
        if b is None:
            continue
        est, lo, hi, n = paired_bootstrap(r.scores, [b.scores])
        verdict = CONVERGED if hi < margin else NOT_CONVERGED if lo > margin else INCONCLUSIVE
        shared = b.scores.keys() & r.scores.keys()  # the episodes the difference is over (none: nan, n = 0)
        means = tuple(sum(x.scores[k] for k in shared) / len(shared) if shared else float("nan") for x in (b, r))
        diffs = {k: r.scores[k] - b.scores[k] for k in sorted(shared)}
        out.append(Check(b.run_label, r.variant, est, lo, hi, n, verdict, r.train_seed, means, diffs))
    return out


@dataclass
class RunVerdict:
    """One run's check over all its settings (module docstring): the pooled paired difference and the verdict."""

    run: str
    train_seed: int | None
    est: float
    lo: float
    hi: float
    n: int  # episodes every pooled setting shares
    pooled: list[str]  # the settings averaged (those where either run scores >= POOL_FLOOR)
    settings: list[Check]  # every setting's own check
    verdict: str

    def table_row(self) -> str:
        names = ", ".join(v.upper() for v in self.pooled) if len(self.pooled) <= 4 else f"{len(self.pooled)} settings"
        seed = f" (training seed {self.train_seed})" if self.train_seed else ""
        return (f"| {self.run}{seed} | {names} (of {len(self.settings)}) | {self.est:+.3f} "
                f"[{self.lo:+.3f}, {self.hi:+.3f}] | {self.n} | **{self.verdict}** |")


def run_verdicts(checks: list[Check], margin: float) -> dict[tuple[str, int | None], RunVerdict]:
    """Each checked (run, training seed)'s verdict: converged if the interval of its pooled difference lies below
    +margin and no setting's own interval lies above it; not converged if the pooled interval or any setting's lies
    above. Settings are pooled within one training seed only (their differences share its episodes)."""
    by_run: dict[tuple[str, int | None], list[Check]] = {}
    for c in checks:
        by_run.setdefault((c.run, c.train_seed), []).append(c)
    out = {}
    for (run, seed), mine in by_run.items():
        pool = [c for c in mine if max(c.means) >= POOL_FLOOR] or mine  # none works: all of them, as they are
        shared = set.intersection(*(set(c.diffs) for c in pool))
        d = np.array([np.mean([c.diffs[k] for c in pool]) for k in sorted(shared)])  # (episodes,)
        est = float(d.mean()) if d.size else float("nan")
        lo, hi = bootstrap_ci(d)
        if lo > margin or any(c.verdict == NOT_CONVERGED for c in mine):
            verdict = NOT_CONVERGED
        else:
            verdict = CONVERGED if hi < margin else INCONCLUSIVE
        out[run, seed] = RunVerdict(run, seed, est, lo, hi, int(d.size), [c.variant for c in pool], mine, verdict)
    return out


def apply_checks(rows: list[Row], checks: list[Check], strict: bool, margin: float
                 ) -> dict[tuple[str, int | None], RunVerdict]:
    """Set each trained row's `converged` from its run's verdict over all its settings (`run_verdicts`): its own
    training seed's where that seed was checked, else every checked seed's (the verdict holds for the preset).
    Returns the verdicts. strict (a study under the seed protocol): a trained run without a check is not shown
    converged; otherwise (older studies) the learning-curve rule stands, and the report says what it is worth."""
    verdicts = run_verdicts(checks, margin)
    for r in rows:
        if r.converged is None or r.doubles:  # baselines; the checking runs themselves
            continue
        own = verdicts.get((r.run_label, r.train_seed))
        mine = [own] if own else [v for (run, _), v in verdicts.items() if run == r.run_label]
        if mine:
            r.converged = all(v.verdict == CONVERGED for v in mine)
            r.check_verdict = (CONVERGED if r.converged else NOT_CONVERGED
                               if any(v.verdict == NOT_CONVERGED for v in mine) else INCONCLUSIVE)
            r.convergence = "; ".join(verdict_text(v) for v in mine)
        elif strict:
            r.converged, r.convergence = False, f"{NO_CHECK} (" + r.convergence + ")"
    return verdicts


def verdict_text(v: RunVerdict) -> str:
    counts = collections.Counter(c.verdict for c in v.settings)
    each = ", ".join(f"{counts[x]} {x}" for x in (NOT_CONVERGED, INCONCLUSIVE, CONVERGED) if counts[x])
    return (f"twice the steps (training seed {v.train_seed}'s check): {v.est:+.3f} [{v.lo:+.3f}, {v.hi:+.3f}] over "
            f"{len(v.pooled)} of {len(v.settings)} settings, {v.verdict}"
            + (f"; setting by setting {each} (tables below)" if len(v.settings) > 1 else ""))


def _widths(verdicts: dict[tuple[str, int | None], RunVerdict]) -> str:
    """How wide one setting's interval is against the pooled one: why a run is judged on the pool."""
    one = [(c.hi - c.lo) / 2 for v in verdicts.values() for c in v.settings if c.variant in v.pooled]
    pooled = [(v.hi - v.lo) / 2 for v in verdicts.values() if len(v.pooled) > 1]
    if not one or not pooled:
        return ""

    def span(xs: list[float]) -> str:  # training seeds that share one check repeat its widths
        lo, hi = f"{min(xs):.3f}", f"{max(xs):.3f}"
        return lo if lo == hi else f"{lo} to {hi}"

    return (f" One setting's interval reaches +/-{span(one)} around its estimate here, the pooled one "
            f"+/-{span(pooled)}: a run that doubling leaves unchanged would pass every one of several settings of "
            f"the former width only by chance.")


def check_lines(verdicts: dict[tuple[str, int | None], RunVerdict], strict: bool, margin: float,
                validation: bool = False) -> list[str]:
    """The twice-the-steps checks (each run's verdict, then every setting's), or what the curve rule above is worth
    when a study has none."""
    if not verdicts:
        return [] if strict else [
            "This study has no twice-the-steps convergence check: 'converged' above is the learning-curve rule (a line "
            "through the last quarter's rollout points rising by less than the margin), which a cosine schedule "
            "passes by construction; read it as 'the curve flattened', not as evidence of convergence.", ""]
    return ["### Twice the steps", "",
            "A run trained again with twice its optimiser steps (same recipe, its own schedule), minus the run, on "
            "the same episodes (paired, two-sided 95%)."
            + (" Compared on validation episodes (seeds 200000+), not on the test seeds of the table; the verdict "
               "holds for every training seed of the preset." if validation else "")
            + f" A run is judged once, on the per-episode difference averaged over its settings (those where either "
            f"run scores at least {POOL_FLOOR}): converged if that interval lies below +{margin}; not converged if it "
            f"lies above, or if any one setting's own interval does (a gain in one sampler is not averaged away)."
            + _widths(verdicts) + " Why: docs/evaluation.md.", "",
            "| run | settings pooled | difference [95%] | episodes | verdict |", "|---|---|---|---|---|",
            *[v.table_row() for v in verdicts.values()], "",
            "Setting by setting (each its own interval; descriptive, except that one lying above the margin makes "
            "its run not converged):", "",
            "| run | setting | the run | twice the steps | difference [95%] | episodes | verdict |",
            "|---|---|---|---|---|---|---|",
            *[c.table_row() for v in verdicts.values() for c in v.settings], ""]
