"""Each learned policy against the scripted baseline: above it, below it, or not told apart, and what bears on why.

The scripted baseline (bcbench.policies.scripted) pushes the T with a hand-written controller and no learning; a
learned policy that does not beat it on the same episodes has learned less than a few lines of geometry. Issue 30
asks for every learned policy above it "or the evidence why not", so the report states, per run:
- its one setting, the choice table's (bcbench.analysis.choose.chosen_settings: fixed by the study file, so the
  comparison picks nothing on the test episodes; a better-scoring sampler setting is not searched for);
- the paired difference to the scripted baseline over the shared episode seeds (bcbench.analysis.findings.
  paired_interval: with several training seeds a t interval over the seeds' paired differences, the baseline
  paired with each seed);
- a verdict: above (interval above 0), below (interval below 0), or not told apart;
- where it is not above, the evidence that bears on why: whether more training would help (its twice-the-steps
  check, or the lack of one) and how its network's size compares with the study's. These are facts beside the
  verdict, not a diagnosis: a converged small network says "more steps do not help this network", not that a
  larger one would beat the baseline.
Reads rows only.
"""

from __future__ import annotations

from typing import Any

from bcbench.analysis.choose import chosen_settings
from bcbench.analysis.convergence import CONVERGED
from bcbench.analysis.findings import paired_interval, points_from_rows
from bcbench.analysis.results import Row
from bcbench.reference import STUDY_PARAMETERS, STUDY_REFERENCE
from bcbench.stats import fmt_estimate

ABOVE, BELOW, APART = "above", "below", "not told apart"
HEADER = ["policy", "setting", "score [95% CI]", "minus scripted [95% CI]", "verdict", "what bears on why not"]
UNTRAINED = ("random", "scripted")


def _verdict(lo: float, hi: float) -> str:
    return ABOVE if lo > 0 else BELOW if hi < 0 else APART


def _why_not(r: Row) -> str:
    """The evidence beside a policy that is not above the baseline: convergence, then size against the study's."""
    if r.converged is True and r.check_verdict == CONVERGED:
        train = "converged: " + r.convergence
    elif r.converged is True:  # an older study without the check: the curve rule, which a cosine schedule passes
        train = "curve flattened (no twice-the-steps check): " + r.convergence
    else:
        train = "not shown converged: " + (r.convergence or "no check")
    size = f"{r.params / 1e6:.2f} M parameters"
    if r.policy in STUDY_PARAMETERS:
        size += f" (the study's network: {STUDY_PARAMETERS[r.policy] / 1e6:.1f} M)"
    study = STUDY_REFERENCE.get(r.policy, {}).get("score")
    if study is not None:
        size += f"; the study's A100 score {study:.2f} (it ran no scripted baseline)"
    return f"{train}; {size}"


def baseline_rows(rows: list[Row], realtime: dict[str, dict[str, Any]]) -> list[list[str]]:
    """One row per learned run (settings merged over training seeds), in the rows' order; [] without a scripted
    baseline with episode scores."""
    scripted = next((r for r in rows if r.policy == "scripted" and r.scores), None)
    if scripted is None:
        return []
    base = points_from_rows([scripted])[0]
    out = []
    for label, r in chosen_settings(rows, realtime).items():
        if r.policy in UNTRAINED or r.doubles:
            continue
        d = paired_interval(points_from_rows([r])[0], [base])
        if d.n == 0:
            continue
        verdict = _verdict(d.lo, d.hi)
        seeds = f", {d.k} training seeds x {d.n} episodes" if d.k > 1 else f", {d.n} episodes"
        setting = r.variant.upper() if r.variant != "default" else (r.preset or "-")
        out.append([label, setting, fmt_estimate(r.summary["mean_score"]),
                    f"{d.est:+.3f} [{d.lo:+.3f}, {d.hi:+.3f}]{seeds}", verdict,
                    "-" if verdict == ABOVE else _why_not(r)])
    return out


def baseline_lines(rows: list[Row], table: list[list[str]]) -> list[str]:
    """The report's section (Markdown lines) around `table` (baseline_rows of `rows`); [] when it is empty."""
    if not table:
        return []
    scripted = next(r for r in rows if r.policy == "scripted" and r.scores)
    above = sum(row[4] == ABOVE for row in table)
    return ["## Against the scripted baseline", "",
            f"The scripted baseline (no learning) scores {fmt_estimate(scripted.summary['mean_score'])} on the same "
            f"episodes. {above} of {len(table)} learned policies are above it. Each policy at its one setting of the "
            "table above (fixed by the study file, not the best-scoring), paired over the shared episode seeds "
            "(several training seeds: a t interval over the seeds' paired differences). Where a policy is not above "
            "it, the last column gives what bears on why: whether more training would lift it (its twice-the-steps "
            "check; older studies have only the learning-curve rule), and its network's size against the study's. "
            "Facts beside the verdict, not a diagnosis.", "",
            "| " + " | ".join(HEADER) + " |", "|---" * len(HEADER) + "|",
            *("| " + " | ".join(row) + " |" for row in table), ""]
