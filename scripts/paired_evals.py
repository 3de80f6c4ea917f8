"""The paired difference of two evaluations of the same episode seeds: B - A, mean over the seeds both hold, with
bcbench's paired percentile-bootstrap 95% interval (bcbench.stats.paired_bootstrap), and how many episodes
scored the same. Reads result files only.

    python scripts/paired_evals.py A/eval.json B/eval.json [--out paired.json]

Use it where one model was run twice under something that should not matter (another device, library or
runtime): an interval inside the margin says it did not, to the resolution of the episodes.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bcbench.analysis.realtime import seed_scores
from bcbench.stats import paired_bootstrap
from bcbench.utils.io import write_json
from bcbench.utils.system import git_commit


def scores(path: Path) -> dict[int, float]:
    try:
        return seed_scores(json.loads(path.read_text()))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SystemExit(f"paired_evals: {path}: not an evaluation result with per-episode scores ({exc})") from None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("a", type=Path)
    p.add_argument("b", type=Path)
    p.add_argument("--out", type=Path, help="also write the result here (JSON)")
    args = p.parse_args(argv)
    a, b = scores(args.a), scores(args.b)
    # paired_bootstrap gives first - second: B first, so the interval is of B - A
    diff, lo, hi, n = paired_bootstrap(b, [a])
    if n == 0:
        print("paired_evals: the two files share no episode seed", file=sys.stderr)
        return 2
    shared = sorted(set(a) & set(b))
    out = {"a": str(args.a), "b": str(args.b), "episodes": n, "mean_a": sum(a[s] for s in shared) / n,
           "mean_b": sum(b[s] for s in shared) / n, "b_minus_a": diff, "ci95": [lo, hi],
           "same_score_episodes": sum(a[s] == b[s] for s in shared)}
    print(f"B - A = {diff:+.3f} [{lo:+.3f}, {hi:+.3f}] over {n} shared episodes "
          f"(A {out['mean_a']:.3f}, B {out['mean_b']:.3f}; {out['same_score_episodes']} scored the same)")
    if args.out:  # stamped with the commit that computed it and those of the files it read
        inputs = {str(f): json.loads(f.read_text()).get("git_commit") for f in (args.a, args.b)}
        write_json(args.out, {**out, "git_commit": git_commit(), "input_commits": inputs})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
