"""How much of naive async's loss to delay other settings get back, split into what the execution horizon buys and
what the method adds (issue 74), from committed real-time records only. Each step is paired over the episode seeds
all records share, with a 95% paired-bootstrap interval (bcbench.stats): per setting its score, its difference to
the step before, and the share of naive's loss, (setting - naive) / (sync - naive) (bcbench.stats.recovered_share).
Pair only records from one machine, or from machines shown to give the same episodes (the closed loop amplifies
last-bit differences between CPUs).

    python scripts/recovery.py --sync A/naive/realtime-sync.json --naive A/naive/realtime-async-d8.json \
        [--naive-at-horizon A/naive-s7/realtime-async-d8.json] B/rtc/realtime-async-d8.json

With --naive-at-horizon (naive at the strategy's execution horizon s) every setting is read from the loss, naive at
the default horizon minus sync (the first line), in two steps:
  1. naive at s minus naive at the default horizon (what the horizon alone buys);
  2. the setting minus naive at s (what the method adds at that horizon);
and the total, the setting minus naive at the default horizon. A retention claim (a setting within the margin of
sync) reads the same steps, each against sync.

A record is one setting's file, or a whole sweep's (a study's real-time stage, `realtime-sweep.json`) with the
setting named after a colon: `RUN/realtime-ddim10.json:realtime-async-d8`. Each argument may also be a group of
replicates (comma-separated records or a quoted glob: the same episodes with other noise or training seeds), whose
per-episode scores are averaged before pairing (`bcbench.analysis.realtime.replicate_scores`; results/strategies-
replicates/). The interval is over episode seeds: for replicates of one trained model it says nothing about other
training seeds, and the output says how many replicates each group holds.
"""

from __future__ import annotations

from bcbench.analysis.realtime import averaged, replicate_scores
from bcbench.errors import BCBenchError
from bcbench.stats import paired_bootstrap, recovered_share
from bcbench.utils.args import OneLineParser


def _mean(v: dict[int, float]) -> float:
    return sum(v.values()) / len(v)


def _step(name: str, now: dict[int, float], before: dict[int, float], sync: dict[int, float],
          naive: dict[int, float], start: dict[int, float] | None) -> str:
    d, dlo, dhi, _ = paired_bootstrap(now, [before])
    ds, slo, shi, _ = paired_bootstrap(now, [sync])
    r, lo, hi, n = recovered_share(sync, naive, now, start=start)
    return (f"{name}: {_mean(now):.3f}; {d:+.3f} [{dlo:+.3f}, {dhi:+.3f}] over the step before, {ds:+.3f} "
            f"[{slo:+.3f}, {shi:+.3f}] against sync; {100 * r:.0f}% [{100 * lo:.0f}, {100 * hi:.0f}] of naive's loss "
            f"({n} shared seeds)")


def main() -> None:
    ap = OneLineParser(prog="recovery.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--sync", required=True, help="naive sync's record (realtime-sync.json)")
    ap.add_argument("--naive", required=True, help="naive async's record at the delay, default horizon (the loss)")
    ap.add_argument("--naive-at-horizon", help="naive async at the strategy's execution horizon (splits each "
                    "setting's recovery into the horizon's step and the method's)")
    ap.add_argument("settings", nargs="+", help="records of the settings compared with it")
    args = ap.parse_args()
    try:
        groups = {"sync": args.sync, "naive": args.naive, **({"naive_s": args.naive_at_horizon}
                                                               if args.naive_at_horizon else {})}
        loaded = {k: replicate_scores(g) for k, g in groups.items()}
        others = [(g, replicate_scores(g)) for g in args.settings]
    except BCBenchError as e:
        ap.error(str(e))
    counts = ", ".join(f"{k} {len(v)}" for k, v in [*loaded.items(), *((f, r) for f, r in others)])
    sync, naive = averaged(loaded["sync"]), averaged(loaded["naive"])
    s, a = _mean(sync), _mean(naive)
    print(f"replicates per group: {counts}")
    d, dlo, dhi, _ = paired_bootstrap(naive, [sync])
    print(f"naive sync {s:.3f}, naive at the delay {a:.3f}: loss {s - a:.3f} (naive at its default horizon; "
          f"{d:+.3f} [{dlo:+.3f}, {dhi:+.3f}] against sync)")
    naive_s = averaged(loaded["naive_s"]) if "naive_s" in loaded else None
    if naive_s is not None:
        print("  1. " + _step("naive at the strategy's horizon", naive_s, naive, sync, naive, None))
    for f, group in others:
        other = averaged(group)
        if naive_s is None:
            d, dlo, dhi, _ = paired_bootstrap(other, [naive])
            r, lo, hi, n = recovered_share(sync, naive, other)
            print(f"{f}: {_mean(other):.3f}, {d:+.3f} [{dlo:+.3f}, {dhi:+.3f}] over naive, "
                  f"recovers {100 * r:.0f}% [{100 * lo:.0f}, {100 * hi:.0f}] of its loss ({n} shared seeds)")
            continue
        print(f"  2. {_step(f + ' (the method, at that horizon)', other, naive_s, sync, naive, naive_s)}")
        print(f"     total: {_step(f, other, naive, sync, naive, None)}")


if __name__ == "__main__":
    main()
