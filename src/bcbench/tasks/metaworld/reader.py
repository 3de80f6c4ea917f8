"""Reader for the MetaWorld demonstration stores `generate` writes (zarr v2, no MuJoCo needed to read them).

Layout: data/img uint8 (N, 96, 96, 3), data/state float32 (N, S) = the task's proprioception, data/action
float32 (N, 4), meta/episode_ends int64 (E,) exclusive ends, meta/seeds int64 (E,) the seed of each episode;
attrs say which task, how it was generated and with which versions. The arrays are Push-T's names, so that the
rest of bcbench reads a `ReplayBuffer` from either; images are uint8 here (Push-T's store holds float32).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bcbench.data.replay_buffer import ReplayBuffer, open_group
from bcbench.errors import DatasetError

FORMAT = "bcbench-metaworld-v1"
ACTION_DIM = 4


def _array(root: Any, key: str, path: Path) -> Any:
    try:
        return root[key]
    except KeyError:
        raise DatasetError(f"{path}: missing key {key} (not a MetaWorld demonstration store?)") from None


def _read(arr: Any, key: str, path: Path) -> np.ndarray:
    try:
        return np.asarray(arr[:])
    except Exception as exc:  # a damaged chunk surfaces as a codec or value error
        raise DatasetError(f"{path}: cannot read {key}: corrupt chunk? ({type(exc).__name__}: {exc})") from None


def _check_shapes(root: Any, path: Path, image_size: int) -> tuple[int, int]:
    """(N, S) after checking every array's shape and dtype; a DatasetError names the first problem."""
    img, state, action = (_array(root, f"data/{k}", path) for k in ("img", "state", "action"))
    ends, seeds = _array(root, "meta/episode_ends", path), _array(root, "meta/seeds", path)
    n = int(img.shape[0])
    if tuple(img.shape[1:]) != (image_size, image_size, 3) or img.dtype != np.uint8:
        raise DatasetError(f"{path}: data/img is {img.dtype} {tuple(img.shape)}, expected uint8 "
                           f"(N, {image_size}, {image_size}, 3)")
    if len(state.shape) != 2 or state.shape[1] < 1:
        raise DatasetError(f"{path}: data/state has shape {tuple(state.shape)}, expected (N, S)")
    if tuple(action.shape[1:]) != (ACTION_DIM,) or len(action.shape) != 2:
        raise DatasetError(f"{path}: data/action has shape {tuple(action.shape)}, expected (N, {ACTION_DIM})")
    for key, arr in (("data/state", state), ("data/action", action)):
        if arr.shape[0] != n:
            raise DatasetError(f"{path}: {key} has {arr.shape[0]} steps but data/img has {n}")
    if len(ends.shape) != 1 or ends.shape[0] == 0 or tuple(seeds.shape) != tuple(ends.shape):
        raise DatasetError(f"{path}: meta/episode_ends {tuple(ends.shape)} and meta/seeds {tuple(seeds.shape)} "
                           "must both be (E,) with E > 0")
    return n, int(state.shape[1])


def load_metaworld_buffer(path: str | Path, *, images: bool = True, image_size: int = 96) -> ReplayBuffer:
    """Load and validate a MetaWorld demonstration store as a `ReplayBuffer` (state = proprioception (N, S),
    action (N, 4), images uint8 (N, 96, 96, 3) or None with `images=False`; no keypoint or n_contacts)."""
    path = Path(path)
    root = open_group(path)
    n, _ = _check_shapes(root, path, image_size)
    ends = _read(root["meta/episode_ends"], "meta/episode_ends", path).astype(np.int64)
    if np.any(np.diff(ends) <= 0) or ends[0] <= 0 or ends[-1] != n:
        raise DatasetError(f"{path}: meta/episode_ends must increase strictly and end at N={n} "
                           f"(ends at {int(ends[-1])})")
    state = _read(root["data/state"], "data/state", path).astype(np.float32)
    action = _read(root["data/action"], "data/action", path).astype(np.float32)
    for key, arr in (("data/state", state), ("data/action", action)):
        if not np.isfinite(arr).all():
            raise DatasetError(f"{path}: {key} holds NaN or infinite values")
    return ReplayBuffer(state=state, action=action, episode_ends=ends,
                        images=_read(root["data/img"], "data/img", path) if images else None,
                        keypoint=None, n_contacts=None, source=str(path))


def store_info(path: str | Path) -> dict[str, Any]:
    """The store's attrs (task, generator settings, counts, versions) and its episode seeds."""
    path = Path(path)
    root = open_group(path)
    info = dict(root.attrs)
    info["seeds"] = _read(_array(root, "meta/seeds", path), "meta/seeds", path).astype(np.int64).tolist()
    return info
