"""Paired differences over replicates of one setting (issue 31's d = 4 goal line), from committed real-time records
only. A replicate is the same setting on the same episode seeds with another noise seed (`--seed`) or another
training seed; each episode seed's score is averaged over a group's replicates before the groups are paired
(`bcbench.analysis.realtime.replicate_scores`, `averaged`), and the interval is the paired bootstrap over the
episode seeds (bcbench.stats), so it is conditional on the models and averages over the sampler's noise. Where the
replicates pair one to one (the same noise or training seed in both groups), the t interval over the replicates'
own differences is printed beside it. The d = 8 line (the share of naive's loss recovered) is `scripts/recovery.py`,
which takes the same groups.

    python scripts/replicates.py diff "F/seed*/rtc-d4/rtc/realtime-async-d4.json" \
        "F/seed*/rtc-d4/rtc/realtime-sync.json"
    python scripts/replicates.py same "F/seed0/*/realtime-sync.json"

A group is a quoted glob or comma-separated records; records from one machine only: the closed loop turns
last-bit differences between CPUs into different episodes.
"""

from __future__ import annotations

from bcbench.analysis.realtime import averaged, replicate_scores
from bcbench.errors import BCBenchError
from bcbench.stats import over_training_seeds, paired_bootstrap
from bcbench.utils.args import OneLineParser


def mean(scores: dict[int, float]) -> float:
    return sum(scores.values()) / len(scores)


def main() -> None:
    ap = OneLineParser(prog="replicates.py", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    d = sub.add_parser("diff", help="a group's averaged score minus another's, paired over episode seeds")
    d.add_argument("a")
    d.add_argument("b")
    s = sub.add_parser("same", help="largest difference of an episode's score between records of one setting")
    s.add_argument("group")
    args = ap.parse_args()
    try:
        groups = [replicate_scores(g) for g in ((args.a, args.b) if args.what == "diff" else (args.group,))]
    except BCBenchError as e:
        ap.error(str(e))

    if args.what == "same":
        reps = groups[0]
        worst = max(abs(x[k] - reps[0][k]) for x in reps for k in x)
        print(f"{len(reps)} records, {len(reps[0])} episodes each: largest difference {worst:.2e}")
        return
    a, b = groups
    diff, lo, hi, n = paired_bootstrap(averaged(a), [averaged(b)])
    print(f"{len(a)} and {len(b)} replicates: {mean(averaged(a)):.3f} - {mean(averaged(b)):.3f} = "
          f"{diff:+.3f} [{lo:+.3f}, {hi:+.3f}] (paired bootstrap over {n} episode seeds)")
    if len(a) == len(b) > 1:
        per = [paired_bootstrap(x, [y])[0] for x, y in zip(a, b, strict=True)]
        t = over_training_seeds(a, [b])
        print(f"per replicate {', '.join(f'{v:+.3f}' for v in per)}; t over the {len(a)} replicates "
              f"{t['value']:+.3f} [{t['ci95'][0]:+.3f}, {t['ci95'][1]:+.3f}]")


if __name__ == "__main__":
    main()
