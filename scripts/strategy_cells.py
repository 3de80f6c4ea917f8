"""The cells of results/strategies-confirm/README.md's default-horizon tables (sections 4-6), from the committed
real-time records only: per strategy and delay, the score, its paired difference to naive sync and (for the other
strategies) to naive at the same d, 95% intervals over the shared episode seeds.

    python scripts/strategy_cells.py results/strategies-confirm/flow-euler10-default

`bcbench realtime --strategy ...` prints the paired difference to naive only (analysis.strategies.strategy_table);
this adds the one to sync, with the same pairing (analysis.realtime.compare)."""

from __future__ import annotations

from bcbench.analysis.realtime import compare
from bcbench.analysis.strategies import TABLE_DELAYS, load_strategy_sweeps
from bcbench.protocol import SYNC_SETTING, delay_setting
from bcbench.utils.args import OneLineParser


def interval(diff: tuple[float, float, float, int]) -> str:
    return f"{diff[0]:+.3f} [{diff[1]:+.3f}, {diff[2]:+.3f}]"


def main() -> None:
    ap = OneLineParser(prog="strategy_cells.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", help="a folder of `bcbench realtime` sweeps, one subfolder per strategy")
    folder = ap.parse_args().folder
    found = load_strategy_sweeps(folder)
    if not found:
        ap.error(f"no sweep with naive and another strategy under '{folder}'")
    for label, sweeps in found.items():
        naive = sweeps["naive"]
        print(f"## {label}\n\n| strategy | " + " | ".join(f"d = {d}" for d in TABLE_DELAYS) + " |")
        print("|---|" + "---|" * len(TABLE_DELAYS))
        for kind, settings in sweeps.items():
            cells = []
            for d in TABLE_DELAYS:
                r = settings.get(delay_setting("async", d))
                if r is None:
                    cells.append("-")
                    continue
                cell = f"{r['summary']['mean_score']['value']:.3f}, {interval(compare(r, naive[SYNC_SETTING]))}"
                same_d = naive.get(delay_setting("async", d))
                cells.append(cell + (f" / {interval(compare(r, same_d))}" if kind != "naive" and same_d else ""))
            print(f"| {kind} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
