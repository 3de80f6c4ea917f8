"""Paired differences and recovered shares over replicates of one setting (issue 31's goal lines), from committed
real-time records only. A replicate is the same setting on the same episode seeds with another noise seed
(`--seed`) or another training seed; each episode seed's score is averaged over a group's replicates before the
groups are paired, and the interval is the paired bootstrap over the episode seeds (bcbench.stats), so it is
conditional on the models and averages over the sampler's noise. Where the replicates pair one to one (the same
noise or training seed in both groups), the t interval over the replicates' own differences is printed beside it.

    python scripts/replicates.py diff "F/seed*/rtc-d4/rtc/realtime-async-d4.json" \
        "F/seed*/rtc-d4/rtc/realtime-sync.json"
    python scripts/replicates.py recovery --sync "F/seed*/naive-d8/naive/realtime-sync.json" \
        --naive "F/seed*/naive-d8/naive/realtime-async-d8.json" "F/seed*/rtc-d8/rtc/realtime-async-d8.json"
    python scripts/replicates.py same "F/seed*/*/*/realtime-sync.json"

A group is a glob (quoted) or a comma-separated list of records; records from one machine only: the closed loop
turns last-bit differences between CPUs into different episodes.
"""

from __future__ import annotations

import glob
from pathlib import Path

from bcbench.analysis.realtime import seed_scores
from bcbench.stats import over_training_seeds, paired_bootstrap, recovered_share
from bcbench.utils.args import OneLineParser
from bcbench.utils.io import read_json


def records(group: str, ap: OneLineParser) -> list[dict[int, float]]:
    """Each record's per-episode scores, in sorted path order (so seed0, seed1, ... pair up across groups)."""
    paths = sorted(p for part in group.split(",") for p in (glob.glob(part) or [part]))
    missing = [p for p in paths if not Path(p).is_file()]
    if missing:
        ap.error(f"no record '{missing[0]}'")
    out = [seed_scores(read_json(p)) for p in paths]
    if any(set(s) != set(out[0]) for s in out):
        ap.error(f"the records of '{group}' do not share their episode seeds: not replicates of one setting")
    return out


def averaged(reps: list[dict[int, float]]) -> dict[int, float]:
    return {k: sum(r[k] for r in reps) / len(reps) for k in reps[0]}


def mean(scores: dict[int, float]) -> float:
    return sum(scores.values()) / len(scores)


def main() -> None:
    ap = OneLineParser(prog="replicates.py", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    d = sub.add_parser("diff", help="a group's averaged score minus another's, paired over episode seeds")
    d.add_argument("a")
    d.add_argument("b")
    r = sub.add_parser("recovery", help="the share of naive's loss a group gets back: (x - naive) / (sync - naive)")
    r.add_argument("--sync", required=True)
    r.add_argument("--naive", required=True)
    r.add_argument("other")
    s = sub.add_parser("same", help="largest difference of an episode's score between records of one setting")
    s.add_argument("group")
    args = ap.parse_args()

    if args.what == "same":
        reps = records(args.group, ap)
        worst = max(abs(x[k] - reps[0][k]) for x in reps for k in x)
        print(f"{len(reps)} records, {len(reps[0])} episodes each: largest difference {worst:.2e}")
        return
    if args.what == "diff":
        a, b = records(args.a, ap), records(args.b, ap)
        diff, lo, hi, n = paired_bootstrap(averaged(a), [averaged(b)])
        print(f"{len(a)} and {len(b)} replicates: {mean(averaged(a)):.3f} - {mean(averaged(b)):.3f} = "
              f"{diff:+.3f} [{lo:+.3f}, {hi:+.3f}] (paired bootstrap over {n} episode seeds)")
        if len(a) == len(b) > 1:
            per = [paired_bootstrap(x, [y])[0] for x, y in zip(a, b, strict=True)]
            t = over_training_seeds(a, [b])
            print(f"per replicate {', '.join(f'{v:+.3f}' for v in per)}; t over the {len(a)} replicates "
                  f"{t['value']:+.3f} [{t['ci95'][0]:+.3f}, {t['ci95'][1]:+.3f}]")
        return
    sync, naive, other = (averaged(records(g, ap)) for g in (args.sync, args.naive, args.other))
    diff, lo, hi, _ = paired_bootstrap(other, [naive])
    share, slo, shi, n = recovered_share(sync, naive, other)
    print(f"sync {mean(sync):.3f}, naive {mean(naive):.3f}, other {mean(other):.3f}: {diff:+.3f} [{lo:+.3f}, "
          f"{hi:+.3f}] over naive, recovers {100 * share:.0f}% [{100 * slo:.0f}, {100 * shi:.0f}] of its loss "
          f"({n} episode seeds)")


if __name__ == "__main__":
    main()
