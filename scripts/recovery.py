"""How much of naive async's loss to delay other settings get back (issue 31's goal at d = 8: at least half),
from committed real-time records only: per setting its score, its paired difference to naive at the delay, and
the share (setting - naive) / (sync - naive), each with a 95% interval over the episode seeds all share
(bcbench.stats.recovered_share). Pair only records from one machine: the closed loop amplifies last-bit
differences between CPUs.

    python scripts/recovery.py --sync A/naive/realtime-sync.json --naive A/naive/realtime-async-d8.json \
        B/rtc/realtime-async-d8.json B/naive/realtime-async-d8.json

A record is one setting's file, or a whole sweep's (a study's real-time stage, `realtime-sweep.json`) with the
setting named after a colon: `RUN/realtime-ddim10.json:realtime-async-d8`. Each argument may also be a group of
replicates (comma-separated records or a quoted glob: the same episodes with other noise or training seeds), whose
per-episode scores are averaged before pairing (`bcbench.analysis.realtime.replicate_scores`; results/strategies-
replicates/).
"""

from __future__ import annotations

from bcbench.analysis.realtime import averaged, replicate_scores
from bcbench.errors import BCBenchError
from bcbench.stats import paired_bootstrap, recovered_share
from bcbench.utils.args import OneLineParser


def main() -> None:
    ap = OneLineParser(prog="recovery.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--sync", required=True, help="naive sync's record (realtime-sync.json)")
    ap.add_argument("--naive", required=True, help="naive async's record at the delay (the loss to recover)")
    ap.add_argument("settings", nargs="+", help="records of the settings compared with it")
    args = ap.parse_args()
    try:
        sync, naive = (averaged(replicate_scores(g)) for g in (args.sync, args.naive))
        others = [(g, averaged(replicate_scores(g))) for g in args.settings]
    except BCBenchError as e:
        ap.error(str(e))
    s, a = (sum(v.values()) / len(v) for v in (sync, naive))
    print(f"naive sync {s:.3f}, naive at the delay {a:.3f}: loss {s - a:.3f}")
    for f, other in others:
        d, dlo, dhi, _ = paired_bootstrap(other, [naive])
        r, lo, hi, n = recovered_share(sync, naive, other)
        print(f"{f}: {sum(other.values()) / len(other):.3f}, {d:+.3f} [{dlo:+.3f}, {dhi:+.3f}] over naive, "
              f"recovers {100 * r:.0f}% [{100 * lo:.0f}, {100 * hi:.0f}] of its loss ({n} shared seeds)")


if __name__ == "__main__":
    main()
