"""How often does each interval over training seeds cover the true mean? The t interval over the seeds' means,
never narrower than the episodes-only interval (`bcbench.stats.over_training_seeds`, what reports show)
against the two-level bootstrap (`two_level_bootstrap`), by simulation, at the design of the confirm studies: k
training seeds x n episodes.

    .venv/bin/python benchmarks/seed_intervals.py [--k 3 5] [--episodes 100] [--reps 400] [--boot 2000]
                [--out results/seed-intervals]

Model: seed j's episode scores are mu + b_j + e_ij with b_j ~ N(0, between^2) (what a training seed changes) and
e_ij ~ N(0, within^2) (episode to episode); true mean mu = 0. `within` 0.25 is about the per-episode spread of a
setting's scores near 0.85 in results/cpu-confirm-dpflow-long; `between` 0.05 about its training seeds' spread
(DP DDPM-100's seed means 0.878, 0.786, 0.888: SD 0.056). Writes coverage.json (every cell, stamped with commit,
CPU and the settings) and prints a table. Seeded: the same numbers on every machine.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bcbench.stats import over_training_seeds
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance

BETWEEN = (0.0, 0.02, 0.05, 0.08)
WITHIN = 0.25


def cell(k: int, n: int, between: float, reps: int, n_boot: int, seed: int) -> dict[str, float]:
    """Coverage and mean width of both intervals over `reps` simulated studies."""
    rng = np.random.default_rng(seed)
    hit = {"t": 0, "bootstrap": 0}
    width = {"t": 0.0, "bootstrap": 0.0}
    for r in range(reps):
        b = rng.normal(0.0, between, k)  # (k,) training-seed effects
        x = b[:, None] + rng.normal(0.0, WITHIN, (k, n))  # (k, n) episode scores
        est = over_training_seeds([dict(enumerate(row)) for row in x], seed=r, n_boot=n_boot)
        for name, (lo, hi) in (("t", est["ci95"]), ("bootstrap", est["ci95_bootstrap"])):
            hit[name] += lo <= 0.0 <= hi
            width[name] += hi - lo
    return {"k": k, "episodes": n, "between_sd": between, "within_sd": WITHIN, "reps": reps,
            "share_between": between**2 / (between**2 + WITHIN**2 / n),
            **{f"coverage_{m}": hit[m] / reps for m in hit}, **{f"width_{m}": width[m] / reps for m in width}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--k", type=int, nargs="+", default=[3, 5])
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--reps", type=int, default=400)
    ap.add_argument("--boot", type=int, default=2000)
    ap.add_argument("--out", default="results/seed-intervals")
    a = ap.parse_args()
    cells = []
    print("| k | between SD | seeds' share | t: coverage, width | two-level bootstrap: coverage, width |")
    print("|---|---|---|---|---|")
    for k in a.k:
        for i, between in enumerate(BETWEEN):
            c = cell(k, a.episodes, between, a.reps, a.boot, seed=1000 * k + i)
            cells.append(c)
            print(f"| {k} | {between:.2f} | {100 * c['share_between']:.0f}% | {100 * c['coverage_t']:.1f}%, "
                  f"{c['width_t']:.3f} | {100 * c['coverage_bootstrap']:.1f}%, {c['width_bootstrap']:.3f} |",
                  flush=True)
    out = Path(a.out)
    write_json(out / "coverage.json", {"type": "seed-interval-coverage", "level": 0.95, "cells": cells,
                                       "settings": vars(a), **provenance()})
    print(f"wrote {out / 'coverage.json'}")


if __name__ == "__main__":
    main()
