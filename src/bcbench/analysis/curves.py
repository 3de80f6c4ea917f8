"""Learning curves from a run's metrics.jsonl, and whether a curve has reached its plateau.

A run trained with `--eval-every` (or `eval_every` in a study spec) logs closed-loop scores on validation
seeds 200000+ as it trains; every epoch it logs the validation loss. The plateau rule below decides
convergence only in studies from before the seed protocol (under a cosine schedule the last quarter is flat
by construction); a study with a `purpose` uses the twice-the-steps check (bcbench.analysis.convergence).
The rule: a curve is flat over the last quarter of training when, with at least 4 rollout points, a line
through the points that span the last quarter (the last point at or before 75% of training, and every
point after it) rises by less than the margin (default 0.05) over that quarter. Training longer would not
have bought a meaningful gain. A line through all the quarter's points rather than its two ends, because a
rollout point on 20 episodes has a standard error of about 0.04. Without such a curve, convergence is not
shown and the findings that rest on the policy read "undertrained".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bcbench.utils.io import read_jsonl

MIN_POINTS = 4


@dataclass
class Curve:
    """Rollout scores and validation losses of one run, against training samples."""

    samples: list[int] = field(default_factory=list)  # at each rollout
    steps: list[int] = field(default_factory=list)
    score: list[float] = field(default_factory=list)
    lo: list[float] = field(default_factory=list)
    hi: list[float] = field(default_factory=list)
    val_samples: list[int] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    rollout_s: float = 0.0  # the rollouts' wall time (eval_wall_s), summed: the study's time counts it apart


def load_curve(run_dir: str | Path) -> Curve:
    c = Curve()
    metrics = Path(run_dir) / "metrics.jsonl"
    if not metrics.exists():
        return c
    # a long run logs its training loss every few steps (tens of thousands of lines); only the rollout and validation
    # lines feed the curve, so the others are skipped before parsing (a report reads ~150 runs' logs)
    wanted = ('"eval_score"', '"val_loss"', '"eval_wall_s"')
    for m in read_jsonl(metrics, keep=lambda line: any(w in line for w in wanted)):
        samples = int(m.get("samples", 0))
        c.rollout_s += float(m.get("eval_wall_s", 0.0))
        if "eval_score" in m:
            c.samples.append(samples)
            c.steps.append(int(m["step"]))
            c.score.append(float(m["eval_score"]["value"]))
            c.lo.append(float(m["eval_score"]["ci95"][0]))
            c.hi.append(float(m["eval_score"]["ci95"][1]))
        if "val_loss" in m:
            c.val_samples.append(samples)
            c.val_loss.append(float(m["val_loss"]))
    return c


def plateau(curve: Curve, margin: float = 0.05) -> tuple[bool, str]:
    """(converged, why): the rise over the last quarter of training of a line fitted to its rollout points."""
    n = len(curve.score)
    if n < MIN_POINTS:
        return False, f"{n} rollout point(s) in its learning curve (needs {MIN_POINTS} to show a plateau)"
    steps, score = np.array(curve.steps, dtype=float), np.array(curve.score)
    quarter = 0.25 * steps.max()
    start = steps[steps <= steps.max() - quarter]
    if start.size == 0:
        return False, "rollout points do not reach back to the start of the last quarter of training"
    keep = steps >= start.max()  # (k,) the points that span the last quarter, k >= 2
    slope = np.polyfit(steps[keep], score[keep], 1)[0]
    rise = float(slope * quarter)
    what = (f"fitted rise over the last quarter {rise:+.3f} ({int(keep.sum())} points, "
            f"last {score[-1]:.3f})")
    return (True, what) if rise < margin else (False, f"still rising: {what}")


def summary(curve: Curve, margin: float = 0.05) -> dict[str, Any]:
    converged, why = plateau(curve, margin)
    return {"converged": converged, "why": why, "points": len(curve.score)}
