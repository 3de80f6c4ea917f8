"""Convergence that a schedule cannot fake: a run with twice the optimiser steps (same recipe, its schedule sized to
them) must not beat the run it checks by more than the margin, on the same validation episodes (issue 30).

A learning curve flat over its last quarter is not evidence of convergence under a cosine schedule: the rate there
is a few percent of its peak, so the curve flattens by construction. The check instead trains a second run
(`doubles = "LABEL"` in the study file) and compares the two, variant by variant, with a paired two-sided 95%
interval of (twice the steps) minus (the run): converged if the interval lies below +margin, not converged if it
lies above, inconclusive otherwise.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

from bcbench.analysis.results import Row
from bcbench.stats import paired_bootstrap

CONVERGED, NOT_CONVERGED, INCONCLUSIVE = "converged", "not converged", "inconclusive"


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
        out.append(Check(b.run_label, r.variant, est, lo, hi, n, verdict, r.train_seed, means))
    return out


def apply_checks(rows: list[Row], checks: list[Check], strict: bool) -> None:
    """Set each trained row's `converged` from its run's checks: converged only if every variant's check says so.
    strict (a study under the seed protocol): a trained run without a check is not shown converged; otherwise
    (older studies) the learning-curve rule stands, and the report says what it is worth."""
    by_run: dict[str, list[Check]] = {}
    for c in checks:
        by_run.setdefault(c.run, []).append(c)
    for r in rows:
        if r.converged is None or r.doubles:  # baselines; the checking runs themselves
            continue
        mine = by_run.get(r.run_label)
        if mine:
            r.converged = all(c.verdict == CONVERGED for c in mine)
            counts = collections.Counter(c.verdict for c in mine)
            r.convergence = f"twice the steps (training seed {mine[0].train_seed}'s check): " + ", ".join(
                f"{counts[v]} {v}" for v in (NOT_CONVERGED, INCONCLUSIVE, CONVERGED) if counts[v]) + (
                f" of {len(mine)} settings (table below)" if len(mine) > 1 else "")
        elif strict:
            r.converged, r.convergence = False, "no twice-the-steps check yet (" + r.convergence + ")"
