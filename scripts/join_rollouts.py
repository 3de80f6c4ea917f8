"""Join rollout stores of one base into one (a DAgger round's union: the states of every round, for one head).

    python scripts/join_rollouts.py OUT.npz A.npz B.npz [...]

`bcbench.data.rollouts.join_rollouts`: the arrays concatenated in the order given (episode ends shifted), the first
store's attributes with `joined_from` listing every input's; stores recorded with other base weights or on another
task are refused in one line (a head trains on one base's states only)."""

from __future__ import annotations

import sys

from bcbench.data.rollouts import join_rollouts
from bcbench.errors import BCBenchError


def join(out: str, paths: list[str]) -> int:
    arrays = join_rollouts(out, paths)
    print(f"{out}: {len(arrays['action'])} steps, {len(arrays['episode_ends'])} episodes from {len(paths)} stores")
    return 0


if __name__ == "__main__":
    if len(sys.argv) < 4:
        print("usage: python scripts/join_rollouts.py OUT.npz A.npz B.npz [...]", file=sys.stderr)
        sys.exit(2)
    try:
        sys.exit(join(sys.argv[1], sys.argv[2:]))
    except BCBenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
