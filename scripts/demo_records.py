"""Record generated demonstration stores as committed result files: what the generator wrote (its attributes: task,
settings, attempted and kept counts, the expert's success rate, versions) and the sha256 of every array, so that a
regeneration with the same arguments can be checked byte for byte against the record.

    python scripts/demo_records.py results/metaworld-demos metaworld/drawer-open metaworld/peg-insert-side
    python scripts/demo_records.py --ensure results/metaworld-demos metaworld/assembly

--ensure is what a new machine runs before a study (scripts/cpu_study.sh does): a task whose store is missing from
its default place (~/.cache/bcbench/data/metaworld/, which a new session's machine does not have) is generated again
with its record's settings (seed_start, noise, the kept count), and every store, new or found, must match its
record's array hashes: a study never trains on demonstrations other than those its committed results name.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
import zarr

from bcbench.errors import BCBenchError
from bcbench.tasks import get_task
from bcbench.tasks.metaworld.generate import generate
from bcbench.tasks.metaworld.reader import store_info
from bcbench.utils.io import read_json, write_json

ARRAYS = ("data/img", "data/state", "data/action", "meta/episode_ends", "meta/seeds")


def record(task_name: str, path: Path | None = None) -> dict:
    """The record of `path` (default: the task's own store)."""
    path = path or get_task(task_name).dataset(None)
    info = store_info(path)
    root = zarr.open_group(str(path), mode="r")
    digests = {k: hashlib.sha256(np.ascontiguousarray(root[k][:]).tobytes()).hexdigest() for k in ARRAYS}
    seeds = info.pop("seeds", [])
    lengths = np.diff(np.concatenate([[0], root["meta/episode_ends"][:]]))
    return {**info, "seeds": {"count": len(seeds), "first": min(seeds), "last": max(seeds)},
            "episode_length": {"min": int(lengths.min()), "median": float(np.median(lengths)),
                               "max": int(lengths.max())},
            "steps": int(lengths.sum()), "arrays_sha256": digests}


def ensure(records: Path, task_name: str, *, progress: bool = True) -> str:
    """Generate `task_name`'s store where it is missing, from its record in `records`; then check the store's arrays
    against the record (a BCBenchError names the arrays that differ). Returns one line saying what was done."""
    short = task_name.split("/", 1)[1]
    rec_path = records / f"{short}.json"
    if not rec_path.is_file():
        raise BCBenchError(f"no record {rec_path} of {task_name}'s demonstrations: nothing says how to generate them")
    rec = read_json(rec_path)
    from bcbench.tasks.metaworld import default_dataset_path

    path = default_dataset_path(short)
    made = not path.is_dir()
    if made:
        gen = rec["generator"]
        generate(short, int(rec["kept"]), path, seed_start=int(gen["seed_start"]), noise=float(gen["noise"]),
                 progress=progress)
    got = record(task_name, path)["arrays_sha256"]
    differ = sorted(k for k, v in rec["arrays_sha256"].items() if got.get(k) != v)
    if differ:
        raise BCBenchError(f"{path}: {', '.join(differ)} differ from {rec_path} ("
                           f"{'generated here with its settings' if made else 'found here'}); move it away to "
                           f"generate it again, or find what changed (MetaWorld/MuJoCo versions: "
                           f"{rec.get('versions')})")
    return f"{task_name}: {'generated' if made else 'found'} {path}, {rec['kept']} episodes, equal to {rec_path}"


def main(argv: list[str]) -> int:
    ensure_mode = argv[:1] == ["--ensure"]
    args = argv[1:] if ensure_mode else argv
    if len(args) < 2 or not all(a.startswith("metaworld/") for a in args[1:]):
        print("usage: demo_records.py [--ensure] RECORDS_DIR metaworld/NAME [...]", file=sys.stderr)
        return 2
    out = Path(args[0])
    try:
        for name in args[1:]:
            if ensure_mode:
                print(ensure(out, name))
            else:
                write_json(out / f"{name.split('/', 1)[1]}.json", record(name))
    except BCBenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
