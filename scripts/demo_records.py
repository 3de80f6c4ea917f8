"""Record generated demonstration stores as committed result files: what the generator wrote (its attributes: task,
settings, attempted and kept counts, the expert's success rate, versions) and the sha256 of every array, so that a
regeneration with the same arguments can be checked byte for byte against the record.

    python scripts/demo_records.py results/metaworld-demos metaworld/drawer-open metaworld/peg-insert-side
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
import zarr

from bcbench.tasks import get_task
from bcbench.tasks.metaworld.reader import store_info
from bcbench.utils.io import write_json

ARRAYS = ("data/img", "data/state", "data/action", "meta/episode_ends", "meta/seeds")


def record(task_name: str) -> dict:
    path = get_task(task_name).dataset(None)
    info = store_info(path)
    root = zarr.open_group(str(path), mode="r")
    digests = {k: hashlib.sha256(np.ascontiguousarray(root[k][:]).tobytes()).hexdigest() for k in ARRAYS}
    seeds = info.pop("seeds", [])
    lengths = np.diff(np.concatenate([[0], root["meta/episode_ends"][:]]))
    return {**info, "seeds": {"count": len(seeds), "first": min(seeds), "last": max(seeds)},
            "episode_length": {"min": int(lengths.min()), "median": float(np.median(lengths)),
                               "max": int(lengths.max())},
            "steps": int(lengths.sum()), "arrays_sha256": digests}


if __name__ == "__main__":
    out = Path(sys.argv[1])
    for name in sys.argv[2:]:
        write_json(out / f"{name.split('/', 1)[1]}.json", record(name))
        print(f"{name}: {out / (name.split('/', 1)[1] + '.json')}")
