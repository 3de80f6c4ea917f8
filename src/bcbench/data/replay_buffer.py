"""Reader for Diffusion Policy's replay-buffer zarr (Chi et al., RSS 2023).

Layout (zarr v2, blosc): data/img (N,96,96,3) float32 0..255, data/state (N,5) = agent x,y, block x,y,
block angle, data/action (N,2), data/keypoint (N,9,2), data/n_contacts (N,1), meta/episode_ends (E,)
exclusive ends. Images are kept as uint8 (4x less memory than the float store), converted chunk by chunk
so that the float32 copy never exists in full.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bcbench.errors import DatasetError

# key -> expected trailing shape (after N)
REQUIRED_KEYS: dict[str, tuple[int, ...]] = {
    "data/img": (96, 96, 3),
    "data/state": (5,),
    "data/action": (2,),
    "data/keypoint": (9, 2),
    "data/n_contacts": (1,),
}


@dataclass
class ReplayBuffer:
    """All demonstration steps of a set of episodes, concatenated in time order."""

    state: np.ndarray  # (N, 5) float32
    action: np.ndarray  # (N, 2) float32
    episode_ends: np.ndarray  # (E,) int64, exclusive
    images: np.ndarray | None = None  # (N, 96, 96, 3) uint8, or None when loaded without images
    keypoint: np.ndarray | None = None  # (N, 9, 2) float32
    n_contacts: np.ndarray | None = None  # (N, 1) float32
    source: str = ""
    missing: tuple[str, ...] = ()  # arrays an import could not fill (zeros): "block_pose", "keypoint", "n_contacts"

    @property
    def n_steps(self) -> int:
        return int(self.state.shape[0])

    @property
    def n_episodes(self) -> int:
        return int(self.episode_ends.shape[0])

    @property
    def episode_starts(self) -> np.ndarray:
        return np.concatenate([[0], self.episode_ends[:-1]]).astype(np.int64)

    @property
    def episode_lengths(self) -> np.ndarray:
        return np.diff(np.concatenate([[0], self.episode_ends])).astype(np.int64)

    def episode_slice(self, i: int) -> slice:
        return slice(int(self.episode_starts[i]), int(self.episode_ends[i]))

    def summary(self) -> dict[str, Any]:
        lengths = self.episode_lengths
        return {
            "path": self.source,
            "episodes": self.n_episodes,
            "steps": self.n_steps,
            "episode_length": {
                "min": int(lengths.min()), "max": int(lengths.max()), "mean": round(float(lengths.mean()), 1)
            },
            "images": None if self.images is None else list(self.images.shape),
            "image_dtype": None if self.images is None else str(self.images.dtype),
            **({"missing": list(self.missing)} if self.missing else {}),
        }


def open_group(path: Path):
    """A zarr store folder opened read-only, or one DatasetError line (a missing folder, not a zarr group)."""
    import zarr  # only where the store is opened: `bcbench report` and the analysis never load it

    if not path.is_dir():
        raise DatasetError(f"dataset not found: {path} is not a folder")
    try:
        return zarr.open_group(str(path), mode="r")
    except Exception as exc:  # zarr raises several types for a folder that is not a group
        raise DatasetError(f"{path} is not a readable zarr group ({type(exc).__name__}: {exc})") from None


def _check_structure(root, path: Path) -> int:
    """Validate keys and shapes; return N. Raises DatasetError naming the first problem."""
    try:
        ends_arr = root["meta/episode_ends"]
    except KeyError:
        raise DatasetError(f"{path}: missing key meta/episode_ends (not a Push-T replay buffer?)") from None
    n = None
    for key, trailing in REQUIRED_KEYS.items():
        try:
            arr = root[key]
        except KeyError:
            raise DatasetError(f"{path}: missing key {key} (not a Push-T replay buffer?)") from None
        if tuple(arr.shape[1:]) != trailing:
            want = ", ".join(map(str, trailing))
            raise DatasetError(f"{path}: {key} has shape {tuple(arr.shape)}, expected (N, {want})")
        if n is None:
            n = int(arr.shape[0])
        elif arr.shape[0] != n:
            raise DatasetError(f"{path}: {key} has {arr.shape[0]} steps but data/img has {n}")
    if len(ends_arr.shape) != 1 or ends_arr.shape[0] == 0:
        raise DatasetError(f"{path}: meta/episode_ends has shape {tuple(ends_arr.shape)}, expected (E,) with E > 0")
    assert n is not None
    return n


def _read(root, key: str, path: Path, sel: Any = slice(None)) -> np.ndarray:
    try:
        return np.asarray(root[key][sel])
    except Exception as exc:  # a damaged chunk surfaces as a codec or value error
        raise DatasetError(f"{path}: cannot read {key}: corrupt chunk? ({type(exc).__name__}: {exc})") from None


def _read_images_uint8(root, path: Path, n: int) -> np.ndarray:
    """Read the float32 image store into a uint8 array, a block of chunks at a time."""
    arr = root["data/img"]
    out = np.empty((n, 96, 96, 3), dtype=np.uint8)
    block = int(arr.chunks[0]) * 8  # a few chunks at once lets zarr decode them concurrently
    for start in range(0, n, block):
        stop = min(n, start + block)
        chunk = _read(root, "data/img", path, slice(start, stop))
        if not np.isfinite(chunk).all():
            raise DatasetError(f"{path}: data/img holds NaN or infinite values near step {start}")
        np.rint(chunk, out=chunk)
        np.clip(chunk, 0, 255, out=chunk)
        out[start:stop] = chunk
    return out


def load_replay_buffer(path: str | Path, *, images: bool = True) -> ReplayBuffer:
    """Load and validate a Push-T replay buffer. `images=False` skips the (slow, large) image store."""
    path = Path(path)
    root = open_group(path)
    n = _check_structure(root, path)
    ends = _read(root, "meta/episode_ends", path).astype(np.int64)
    if np.any(np.diff(ends) <= 0) or ends[0] <= 0 or ends[-1] != n:
        raise DatasetError(
            f"{path}: meta/episode_ends must increase strictly and end at N={n} (ends at {int(ends[-1])})"
        )
    state = _read(root, "data/state", path).astype(np.float32)
    action = _read(root, "data/action", path).astype(np.float32)
    for name, arr in (("data/state", state), ("data/action", action)):
        if not np.isfinite(arr).all():
            raise DatasetError(f"{path}: {name} holds NaN or infinite values")
    return ReplayBuffer(
        state=state,
        action=action,
        episode_ends=ends,
        images=_read_images_uint8(root, path, n) if images else None,
        keypoint=_read(root, "data/keypoint", path).astype(np.float32),
        n_contacts=_read(root, "data/n_contacts", path).astype(np.float32),
        source=str(path),
        missing=tuple(root.attrs.get("bcbench_missing", ())),
    )


def write_replay_buffer(path: str | Path, buf: ReplayBuffer, chunk: int = 161) -> Path:
    """Write a buffer in Diffusion Policy's zarr v2 layout (float32 images), e.g. for test fixtures."""
    import numcodecs  # as zarr above
    import zarr

    assert buf.images is not None and buf.keypoint is not None and buf.n_contacts is not None
    comp = numcodecs.Blosc(cname="zstd", clevel=5, shuffle=numcodecs.Blosc.BITSHUFFLE)
    root = zarr.open_group(str(path), mode="w", zarr_format=2)
    arrays = {
        "data/img": buf.images.astype(np.float32),
        "data/state": buf.state.astype(np.float32),
        "data/action": buf.action.astype(np.float32),
        "data/keypoint": buf.keypoint.astype(np.float32),
        "data/n_contacts": buf.n_contacts.astype(np.float32),
    }
    for key, data in arrays.items():
        a = root.create_array(key, shape=data.shape, chunks=(chunk, *data.shape[1:]), dtype=data.dtype,
                              compressors=comp)
        a[:] = data
    ends = root.create_array("meta/episode_ends", shape=buf.episode_ends.shape, dtype=np.int64, compressors=comp)
    ends[:] = buf.episode_ends
    if buf.missing:  # an import without the block pose: zeros stand in, and the store says so
        root.attrs["bcbench_missing"] = list(buf.missing)
    return Path(path)


def subset(buf: ReplayBuffer, episodes: list[int] | np.ndarray) -> ReplayBuffer:
    """A new buffer holding only the given episodes, in the given order."""
    idx = np.concatenate([np.arange(buf.episode_starts[e], buf.episode_ends[e]) for e in episodes])
    lengths = buf.episode_lengths[np.asarray(episodes)]

    def take(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else a[idx]

    return ReplayBuffer(
        state=buf.state[idx], action=buf.action[idx], episode_ends=np.cumsum(lengths).astype(np.int64),
        images=take(buf.images), keypoint=take(buf.keypoint), n_contacts=take(buf.n_contacts), source=buf.source,
        missing=buf.missing,
    )
