"""The sha256 of every file `export_lerobot` writes for a fixed small Push-T buffer (PNG frames and AV1 video),
written by the code of any commit: the byte-identity check of Push-T's LeRobot export across the task interface.

    python tests/golden/make_lerobot_golden.py OUT.json      (run at dc2fca9, before export took a task)
tests/test_lerobot_tasks.py exports the same buffer with today's code and compares every file's bytes. The
versions of the libraries that write the bytes (pyarrow: parquet; Pillow: PNG; PyAV: the mp4) are kept beside
the digests: under other versions only the JSON files (which those libraries do not write) are comparable.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: `tests` importable

import numpy as np
from tests.conftest import make_synthetic_buffer

from bcbench.data.lerobot_format import export_lerobot

LENGTHS = (3, 6, 4)


def golden_buffer():
    buf = make_synthetic_buffer(LENGTHS, seed=7)
    buf.images = np.clip(np.rint(buf.images), 0, 255).astype(np.uint8)  # as load_replay_buffer gives them
    return buf


def library_versions() -> dict[str, str]:
    import av
    import PIL
    import pyarrow

    return {"pyarrow": pyarrow.__version__, "Pillow": PIL.__version__, "av": av.__version__}


def digests(task: object = None) -> dict[str, dict[str, str]]:
    """{"png" | "video": {relative path: sha256 of its bytes}} of the golden buffer's two exports (`task`: passed
    to export_lerobot where given; the code before the task interface takes none)."""
    out: dict[str, dict[str, str]] = {}
    kw = {} if task is None else {"task": task}
    with tempfile.TemporaryDirectory() as tmp:
        for kind in ("png", "video"):
            dest = Path(export_lerobot(golden_buffer(), Path(tmp) / kind, video=kind == "video", **kw)["path"])
            out[kind] = {p.relative_to(dest).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
                         for p in sorted(dest.rglob("*")) if p.is_file()}
    return out


if __name__ == "__main__":
    Path(sys.argv[1]).write_text(json.dumps({"versions": library_versions(), "digests": digests()}, indent=1) + "\n")
