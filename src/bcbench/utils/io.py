"""Atomic file writes: a reader never sees a half-written result, whatever kills the writer."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from bcbench.errors import BCBenchError


def _json_default(obj: Any) -> Any:
    # numpy scalars and arrays show up everywhere in results; write them as plain JSON.
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in the same folder; rename it onto `path` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp makes 0600; results should be readable like any file
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as f:  # flush to disk before the rename makes it visible
            os.fsync(f.fileno())
        os.replace(tmp_path, path)
    finally:
        tmp_path.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_dir(path: str | Path, force: bool = False) -> Iterator[Path]:
    """Yield a folder path to create inside a temporary folder beside `path`; it takes `path`'s place only if
    the block succeeds (an existing `path` needs `force`, and is replaced only then)."""
    path = Path(path)
    if path.exists() and not force:
        raise BCBenchError(f"{path} already exists; pass --force to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{path.name}.", dir=path.parent) as tmp:
        staged = Path(tmp) / path.name
        yield staged
        if path.exists():
            shutil.rmtree(path)
        staged.rename(path)


def write_json(path: str | Path, data: Any) -> Path:
    """Write `data` as indented JSON, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=_json_default) + "\n")
    return Path(path)


def read_json(path: str | Path) -> Any:
    return json.loads(Path(path).read_text())


def append_jsonl(path: str | Path, record: dict[str, Any]) -> None:
    """Append one line; a crash can at worst leave a partial last line, which readers skip."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        f.write(json.dumps(record, default=_json_default) + "\n")
        f.flush()
        os.fsync(f.fileno())


def read_jsonl(path: str | Path, keep: Callable[[str], bool] | None = None) -> list[dict[str, Any]]:
    """Read every complete line of a JSON Lines file (a torn last line is ignored); with `keep`, only the lines
    whose text it accepts are parsed."""
    out = []
    path = Path(path)
    if not path.exists():
        return out
    for line in path.read_text().splitlines():
        if keep is not None and not keep(line):
            continue
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return out


def write_jsonl(path: str | Path, records: list[dict[str, Any]]) -> None:
    """Replace a JSON Lines file atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text("".join(json.dumps(r, default=_json_default) + "\n" for r in records))


def safe_name(text: str) -> str:
    """A file-system-safe name: 'my_pkg.mod:make' -> 'my_pkg.mod-make' (letters, digits, . _ - kept)."""
    return "".join(c if c.isalnum() or c in "._-" else "-" for c in text).strip("-") or "policy"


def sha256_file(path: str | Path) -> str:
    """The sha256 of a file's bytes (weights, normalizers): what a record names to say which model it ran."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()
