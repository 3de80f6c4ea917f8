"""Join rollout stores of one base into one (a DAgger round's union: the states of every round, for one head).

    python scripts/join_rollouts.py OUT.npz A.npz B.npz [...]

The arrays are concatenated in the order given (episode ends shifted); the attributes are the first store's, with
`joined_from` listing every input's path and attributes. Stores recorded with other base weights or on another task
are refused in one line (a head trains on one base's states only)."""

from __future__ import annotations

import json
import sys

import numpy as np

from bcbench.data.rollouts import load_rollouts, rollout_attrs
from bcbench.errors import BCBenchError
from bcbench.utils.io import atomic_path


def join(out: str, paths: list[str]) -> int:
    attrs = [rollout_attrs(p) for p in paths]
    for key in ("task", "weights"):
        seen = {json.dumps(a.get("task") if key == "task" else a.get("policy", {}).get("weights_sha256"))
                for a in attrs}
        if len(seen) != 1:
            raise BCBenchError(f"the stores differ in {key} ({', '.join(sorted(seen))}): join one base's rollouts")
    for p in paths:
        load_rollouts(p)  # refuses a damaged store in one line
    stores = [np.load(p, allow_pickle=False) for p in paths]  # the arrays as recorded, dtypes kept
    offsets = np.cumsum([0] + [len(z["action"]) for z in stores[:-1]])
    arrays = {k: np.concatenate([z[k] for z in stores]) for k in ("img", "state", "action", "seeds")}
    arrays["episode_ends"] = np.concatenate([z["episode_ends"] + o for z, o in zip(stores, offsets, strict=True)])
    meta = {**attrs[0], "joined_from": [{"path": p, "attrs": a} for p, a in zip(paths, attrs, strict=True)]}
    with atomic_path(out) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, attrs=np.array(json.dumps(meta)), **arrays)
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
