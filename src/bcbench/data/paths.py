"""Where the Push-T demonstrations are: a flag, then $BCBENCH_DATA, then the usual places."""

from __future__ import annotations

import os
from pathlib import Path

from bcbench.errors import DatasetError

ZARR_NAME = "pusht_cchi_v7_replay.zarr"
ENV_VAR = "BCBENCH_DATA"
OFFICIAL_URL = "https://diffusion-policy.cs.columbia.edu/data/training/pusht.zip"


def data_home() -> Path:
    """Where `bcbench data fetch` puts the dataset by default ($BCBENCH_HOME or ~/.cache/bcbench)."""
    home = os.environ.get("BCBENCH_HOME")
    return Path(home) if home else Path.home() / ".cache" / "bcbench"


def default_fetch_dest() -> Path:
    return data_home() / "data" / "pusht" / ZARR_NAME


def candidate_paths() -> list[Path]:
    """Places searched when neither the flag nor $BCBENCH_DATA names the dataset."""
    repo = Path(__file__).resolve().parents[3]  # src/bcbench/data/paths.py -> repo root
    beside = [repo.parent / "shared" / "data" / "pusht" / ZARR_NAME]
    cwd = [Path.cwd().parent / "shared" / "data" / "pusht" / ZARR_NAME]
    return [*beside, *cwd, default_fetch_dest()]


def resolve_dataset(path: str | os.PathLike[str] | None = None) -> Path:
    """Return the dataset folder to read, or raise a DatasetError that says how to get one."""
    if path is not None:
        chosen, origin = Path(path), "--data"
    elif os.environ.get(ENV_VAR):
        chosen, origin = Path(os.environ[ENV_VAR]), f"${ENV_VAR}"
    else:
        for cand in candidate_paths():
            if cand.is_dir():
                return cand
        raise DatasetError(
            "no Push-T dataset found: run `bcbench data fetch` (downloads pusht.zip), "
            f"`bcbench data fetch --from ZIP_OR_DIR`, or set {ENV_VAR}=/path/to/{ZARR_NAME}"
        )
    if not chosen.exists():
        raise DatasetError(f"dataset not found at {chosen} (from {origin}); run `bcbench data fetch` to get one")
    if not chosen.is_dir():
        raise DatasetError(f"dataset path {chosen} (from {origin}) is not a zarr folder")
    return chosen
