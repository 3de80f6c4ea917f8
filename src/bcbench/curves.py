"""Learning curves from a run's metrics.jsonl, and whether a curve has reached its plateau.

A run trained with `--eval-every` (or `eval_every` in a study spec) logs closed-loop scores on validation
seeds 200000+ as it trains; every epoch it logs the validation loss. A policy counts as converged when
its curve has at least 4 rollout points and the mean score over the last quarter of training is not
higher than the mean over the quarter before it by more than the margin (default 0.05): training longer
would not have bought a meaningful gain. Without such a curve, convergence is not shown and the findings
that rest on the policy read "undertrained".
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


def load_curve(run_dir: str | Path) -> Curve:
    c = Curve()
    metrics = Path(run_dir) / "metrics.jsonl"
    if not metrics.exists():
        return c
    for m in read_jsonl(metrics):
        samples = int(m.get("samples", 0))
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
    """(converged, why): the last quarter's mean score against the quarter before it."""
    n = len(curve.score)
    if n < MIN_POINTS:
        return False, f"{n} rollout point(s) in its learning curve (needs {MIN_POINTS} to show a plateau)"
    last_step = max(curve.steps)
    steps, score = np.array(curve.steps), np.array(curve.score)
    last = score[steps > 0.75 * last_step]
    before = score[(steps > 0.5 * last_step) & (steps <= 0.75 * last_step)]
    if last.size == 0 or before.size == 0:
        return False, "rollout points do not cover the last two quarters of training"
    gain = float(last.mean() - before.mean())
    if gain < margin:
        return True, f"last-quarter mean score {last.mean():.3f} vs {before.mean():.3f} before (gain {gain:+.3f})"
    return False, f"still rising: last-quarter mean {last.mean():.3f} vs {before.mean():.3f} (gain {gain:+.3f})"


def summary(curve: Curve, margin: float = 0.05) -> dict[str, Any]:
    converged, why = plateau(curve, margin)
    return {"converged": converged, "why": why, "points": len(curve.score)}
