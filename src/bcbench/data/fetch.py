"""`bcbench data fetch`: download the official pusht.zip, or import a local zip or folder, then verify.

The result lands atomically: it is unpacked into a temporary folder beside the destination and renamed
into place only after the structure checks pass, so an interrupted fetch never leaves a half dataset.
"""

from __future__ import annotations

import shutil
import tempfile
import urllib.request
import zipfile
from pathlib import Path
from typing import Any

from tqdm import tqdm

from bcbench.data.paths import OFFICIAL_URL, ZARR_NAME, default_fetch_dest
from bcbench.data.replay_buffer import load_replay_buffer
from bcbench.errors import DatasetError


def _find_zarr(root: Path) -> Path:
    """The replay-buffer folder inside an unpacked archive or a user-given folder."""
    if (root / ".zgroup").exists() and (root / "data").is_dir():
        return root
    hits = sorted(p.parent for p in root.rglob(".zgroup") if (p.parent / "data").is_dir())
    named = [p for p in hits if p.name == ZARR_NAME]
    if named or hits:
        return (named or hits)[0]
    raise DatasetError(f"no zarr replay buffer (a folder with .zgroup and data/) found in {root}")


def _download(url: str, dest: Path, progress: bool) -> None:
    try:
        with urllib.request.urlopen(url, timeout=60) as resp, open(dest, "wb") as f:
            total = int(resp.headers.get("Content-Length") or 0) or None
            with tqdm(total=total, unit="B", unit_scale=True, desc="pusht.zip", disable=not progress) as bar:
                while chunk := resp.read(1 << 20):
                    f.write(chunk)
                    bar.update(len(chunk))
    except OSError as exc:
        raise DatasetError(f"download of {url} failed ({exc}); with a local copy use `--from ZIP_OR_DIR`") from None


def fetch(source: str | Path | None = None, dest: str | Path | None = None, *, url: str = OFFICIAL_URL,
          force: bool = False, progress: bool = True) -> dict[str, Any]:
    """Install the Push-T replay buffer at `dest` from `source` (zip or folder) or from `url`.

    Returns the dataset summary. Raises DatasetError on any problem, leaving `dest` untouched.
    """
    dest = Path(dest) if dest is not None else default_fetch_dest()
    if dest.exists() and not force:
        raise DatasetError(f"{dest} already exists; pass --force to replace it")
    dest.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".bcbench-fetch-", dir=dest.parent) as tmp_str:
        tmp = Path(tmp_str)
        if source is None:
            archive = tmp / "pusht.zip"
            _download(url, archive, progress)
        else:
            archive = Path(source)
            if not archive.exists():
                raise DatasetError(f"--from {archive}: no such file or folder")
        if archive.is_dir():
            staged = tmp / ZARR_NAME
            shutil.copytree(_find_zarr(archive), staged)
        else:
            if not zipfile.is_zipfile(archive):
                raise DatasetError(f"{archive} is not a zip archive")
            unpacked = tmp / "unpacked"
            try:
                with zipfile.ZipFile(archive) as zf:
                    zf.extractall(unpacked)
            except (zipfile.BadZipFile, OSError) as exc:
                raise DatasetError(f"cannot unpack {archive}: {exc}") from None
            staged = _find_zarr(unpacked)
        summary = load_replay_buffer(staged, images=True).summary()  # full verification, images included
        if dest.exists():
            shutil.rmtree(dest)
        staged.rename(dest)
    summary["path"] = str(dest)
    return summary
