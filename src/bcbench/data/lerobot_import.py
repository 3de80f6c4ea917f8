"""`bcbench data import --from lerobot DIR [--task NAME]`: a task's LeRobot v3.0 dataset (Push-T's by default)
into bcbench's replay buffer.

Reads parquet with pyarrow and AV1 video with PyAV (frames matched to rows by timestamp, within LeRobot's
own tolerance of 1e-4 s); PNG frames stored in the parquet are decoded with Pillow. The format and the
feature mapping are described in `bcbench.data.lerobot_format`; the dataset is checked against the task's widths,
frame size and rate. Every problem is one `DatasetError` line.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from bcbench.data.lerobot_format import (
    CODEBASE_VERSION,
    EXTRA,
    IMAGE_KEY,
    STATE_EXTRA,
    Layout,
    TaskLike,
    _require_backends,
    layout,
)
from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.errors import DatasetError

TOLERANCE_S = 1e-4  # LeRobot's default tolerance between a row's timestamp and its video frame
ROW_COLUMNS = ("index", "episode_index", "frame_index", "timestamp")


def _info(src: Path, lay: Layout) -> dict[str, Any]:
    path = src / "meta" / "info.json"
    if not path.is_file():
        raise DatasetError(f"{src}: no meta/info.json (not a LeRobot dataset folder)")
    try:
        info = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise DatasetError(f"{path}: not valid JSON ({e})") from None
    version = info.get("codebase_version")
    if version != CODEBASE_VERSION:
        raise DatasetError(f"{src}: LeRobot dataset format {version}, this reader takes {CODEBASE_VERSION} (convert "
                           "older datasets with LeRobot's `lerobot.scripts.convert_dataset_v21_to_v30`)")
    features = info.get("features") or {}
    image, shape = features.get(IMAGE_KEY), [lay.image_size, lay.image_size, 3]
    if image is None:
        raise DatasetError(f"{src}: no feature '{IMAGE_KEY}' in meta/info.json ({lay.label}'s camera)")
    if image.get("dtype") not in ("image", "video") or list(image.get("shape", [])) != shape:
        raise DatasetError(f"{src}: feature '{IMAGE_KEY}' is {image.get('dtype')} {image.get('shape')}, expected an "
                           f"image or video of shape {shape}")
    required = {"observation.state": lay.state_dim, "action": lay.action_dim}
    for key, width in {**required, **EXTRA}.items():
        if key in required and key not in features:
            raise DatasetError(f"{src}: no feature '{key}' in meta/info.json ({lay.label} needs it)")
        if key in features and list(features[key].get("shape", [])) != [width]:
            raise DatasetError(f"{src}: feature '{key}' has shape {features[key].get('shape')}, expected [{width}]")
    rest = features.get(STATE_EXTRA, {}).get("shape") if not lay.pusht and STATE_EXTRA in features else [1]
    if not (isinstance(rest, list) and len(rest) == 1 and isinstance(rest[0], int) and rest[0] > 0):
        raise DatasetError(f"{src}: feature '{STATE_EXTRA}' has shape {rest}, expected [K] with K > 0")
    fps = info.get("fps", lay.fps)
    if not isinstance(fps, int | float) or abs(float(fps) - lay.fps) > 1e-9:
        raise DatasetError(f"{src}: recorded at {fps} fps; {lay.label} runs at {lay.fps}")
    return info


def _read_parquets(folder: Path, columns: list[str] | None = None) -> Any:
    import pyarrow as pa
    import pyarrow.parquet as pq

    files = sorted(folder.glob("chunk-*/file-*.parquet"))
    if not files:
        raise DatasetError(f"{folder}: no chunk-*/file-*.parquet files")
    tables = []
    for f in files:
        try:
            names = pq.read_schema(f).names
            missing = [c for c in columns or [] if c not in names]
            if missing:
                raise DatasetError(f"{f}: missing column(s) {', '.join(missing)}")
            tables.append(pq.read_table(f, columns=columns))
        except DatasetError:
            raise
        except Exception as e:  # a damaged file: pyarrow raises several types
            raise DatasetError(f"{f}: unreadable parquet ({type(e).__name__}: {e})") from None
    return pa.concat_tables(tables)


def _vectors(table: Any, key: str, width: int, src: Path) -> np.ndarray:
    import pyarrow as pa

    col = table.column(key).combine_chunks()
    is_list = pa.types.is_list(col.type) or pa.types.is_fixed_size_list(col.type)
    try:
        values = np.asarray((col.flatten() if is_list else col).to_numpy(zero_copy_only=False), dtype=np.float32)
        out = values.reshape(len(table), width)
    except (ValueError, TypeError):
        raise DatasetError(f"{src}: column '{key}' does not hold {width} numbers per frame") from None
    if not np.isfinite(out).all():
        raise DatasetError(f"{src}: column '{key}' holds NaN or infinite values")
    return out


def _png_frames(table: Any, src: Path, shape: tuple[int, int, int]) -> np.ndarray:
    from PIL import Image

    cells = table.column(IMAGE_KEY).to_pylist()
    out = np.empty((len(cells), *shape), dtype=np.uint8)
    for i, cell in enumerate(cells):
        try:
            img = np.asarray(Image.open(io.BytesIO(cell["bytes"])).convert("RGB"))
        except Exception as e:
            raise DatasetError(f"{src}: frame {i} of '{IMAGE_KEY}' is not a readable image ({e})") from None
        if img.shape != shape:
            raise DatasetError(f"{src}: frame {i} of '{IMAGE_KEY}' is {img.shape}, expected {shape}")
        out[i] = img
    return out


def _decode_video(path: Path, shape: tuple[int, int, int]) -> tuple[np.ndarray, list[np.ndarray]]:
    """All frames of a video file: their timestamps (s) and RGB arrays, as LeRobot's PyAV decoder makes them."""
    _, av = _require_backends()
    times, frames = [], []
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            for frame in container.decode(stream):
                if frame.pts is None:
                    continue
                times.append(float(frame.pts * stream.time_base))
                frames.append(frame.to_ndarray(format="rgb24"))
    except Exception as e:
        raise DatasetError(f"{path}: cannot decode video ({type(e).__name__}: {e})") from None
    if not frames or frames[0].shape != shape:
        raise DatasetError(f"{path}: no {shape[1]}x{shape[0]} RGB frames")
    order = np.argsort(times, kind="stable")  # presentation order, whatever order the decoder gave them in
    return np.asarray(times)[order], [frames[i] for i in order]


def _nearest(times: np.ndarray, want: np.ndarray) -> np.ndarray:
    """Index of the frame time nearest each wanted time; `times` ascending (a video's presentation order)."""
    if len(times) == 1:
        return np.zeros(len(want), dtype=np.int64)
    right = np.clip(np.searchsorted(times, want), 1, len(times) - 1)
    left = right - 1
    return np.where(np.abs(times[left] - want) <= np.abs(times[right] - want), left, right)


def _video_frames(src: Path, info: dict[str, Any], episodes: dict[str, np.ndarray], order: np.ndarray,
                  timestamps: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """The frame of each row (rows in episode order), from the episodes' spans in their video files."""
    template = info.get("video_path")
    if not template:
        raise DatasetError(f"{src}: '{IMAGE_KEY}' is a video feature but meta/info.json has no video_path")
    prefix = f"videos/{IMAGE_KEY}/"
    for col in ("chunk_index", "file_index", "from_timestamp"):
        if prefix + col not in episodes:
            raise DatasetError(f"{src}: meta/episodes lacks column '{prefix + col}'")
    out = np.empty((len(timestamps), *shape), dtype=np.uint8)
    cache: dict[Path, tuple[np.ndarray, list[np.ndarray]]] = {}
    row = 0
    for e in order:
        path = src / template.format(video_key=IMAGE_KEY, chunk_index=int(episodes[prefix + "chunk_index"][e]),
                                     file_index=int(episodes[prefix + "file_index"][e]))
        if not path.is_file():
            raise DatasetError(f"{src}: missing video file {path.relative_to(src)}")
        if path not in cache:
            cache = {path: _decode_video(path, shape)}  # episodes come file by file: keep one file decoded
        times, frames = cache[path]
        n = int(episodes["length"][e])
        want = episodes[prefix + "from_timestamp"][e] + timestamps[row:row + n]
        nearest = _nearest(times, want)
        off = np.abs(times[nearest] - want)
        if off.max() >= TOLERANCE_S:
            raise DatasetError(f"{path}: episode {int(episodes['episode_index'][e])} has no frame within "
                               f"{TOLERANCE_S} s of timestamp {float(want[off.argmax()]):.4f}")
        out[row:row + n] = np.stack([frames[i] for i in nearest])
        row += n
    return out


def _episodes(src: Path) -> dict[str, np.ndarray]:
    ep_table = _read_parquets(src / "meta" / "episodes")
    need = ["episode_index", "length", "dataset_from_index", "dataset_to_index"]
    if [c for c in need if c not in ep_table.column_names]:
        raise DatasetError(f"{src}: meta/episodes lacks one of {', '.join(need)}")
    return {c: np.asarray(ep_table.column(c).to_numpy(zero_copy_only=False)) for c in ep_table.column_names
            if not c.startswith("stats/") and c != "tasks"}


def _in_episode_order(table: Any, episodes: dict[str, np.ndarray], order: np.ndarray, src: Path) -> Any:
    """The data rows episode by episode (in `order`), frames in frame order; checked against meta/episodes."""
    position = {int(v): i for i, v in enumerate(table.column("index").to_numpy())}
    rows = []
    for e in order:
        lo, hi, n = (int(episodes[k][e]) for k in ("dataset_from_index", "dataset_to_index", "length"))
        if hi - lo != n or n <= 0:
            raise DatasetError(f"{src}: episode {int(episodes['episode_index'][e])} spans [{lo}, {hi}) but has "
                               f"length {n}")
        try:
            rows.append(np.array([position[i] for i in range(lo, hi)]))
        except KeyError as k:
            raise DatasetError(f"{src}: episode {int(episodes['episode_index'][e])} names frame index {k} that the "
                               "data files lack") from None
    table = table.take(np.concatenate(rows))
    ep_of_row = np.repeat(episodes["episode_index"][order], episodes["length"][order])
    if not np.array_equal(table.column("episode_index").to_numpy(), ep_of_row):
        raise DatasetError(f"{src}: the data rows' episode_index disagrees with meta/episodes")
    frame_expect = np.concatenate([np.arange(int(n)) for n in episodes["length"][order]])
    if not np.array_equal(table.column("frame_index").to_numpy(), frame_expect):
        raise DatasetError(f"{src}: frame_index does not run 0 .. length-1 within every episode")
    return table


def _arrays(table: Any, lay: Layout, features: dict[str, Any], src: Path) -> dict[str, Any]:
    """state, keypoint, n_contacts and missing of the buffer. Push-T: the bcbench.* columns a dataset lacks are
    zeros and named in `missing`; another task: its extra state columns where the dataset has them, keypoints and
    contacts None where it has none."""
    n = len(table)

    def column(key: str, width: int, absent: np.ndarray | None) -> np.ndarray | None:
        return _vectors(table, key, width, src) if key in features else absent

    state = _vectors(table, "observation.state", lay.state_dim, src)
    if lay.pusht:
        block, keypoint, contacts = (column(k, w, np.zeros((n, w), np.float32)) for k, w in EXTRA.items())
        assert block is not None and keypoint is not None
        return {"state": np.concatenate([state, block], axis=1), "keypoint": keypoint.reshape(n, 9, 2),
                "n_contacts": contacts, "missing": tuple(k.removeprefix("bcbench.") for k in EXTRA
                                                         if k not in features)}
    rest = column(STATE_EXTRA, int(features.get(STATE_EXTRA, {}).get("shape", [0])[0]), None)
    keypoint = column("bcbench.keypoint", EXTRA["bcbench.keypoint"], None)
    return {"state": state if rest is None else np.concatenate([state, rest], axis=1),
            "keypoint": None if keypoint is None else keypoint.reshape(n, 9, 2),
            "n_contacts": column("bcbench.n_contacts", 1, None), "missing": ()}


def import_lerobot(src: str | Path, task: TaskLike | None = None) -> ReplayBuffer:
    """Read a LeRobot v3.0 dataset of `task` (None: Push-T), checked against the task's shapes and rate; the
    episodes in episode_index order, frames in frame order."""
    _require_backends()
    src = Path(src)
    if not src.is_dir():
        raise DatasetError(f"{src}: no such folder")
    lay = layout(task)
    info = _info(src, lay)
    features = info["features"]
    video = features[IMAGE_KEY]["dtype"] == "video"
    extra = [k for k in (*EXTRA, *([] if lay.pusht else [STATE_EXTRA])) if k in features]
    columns = [*ROW_COLUMNS, "observation.state", "action", *extra, *([] if video else [IMAGE_KEY])]
    table = _read_parquets(src / "data", columns)
    episodes = _episodes(src)
    order = np.argsort(episodes["episode_index"], kind="stable")
    table = _in_episode_order(table, episodes, order, src)
    shape = (lay.image_size, lay.image_size, 3)
    timestamps = table.column("timestamp").to_numpy().astype(np.float64)
    images = (_video_frames(src, info, episodes, order, timestamps, shape) if video
              else _png_frames(table, src, shape))
    lengths = episodes["length"][order].astype(np.int64)
    return ReplayBuffer(action=_vectors(table, "action", lay.action_dim, src), episode_ends=np.cumsum(lengths),
                        images=images, source=str(src), **_arrays(table, lay, features, src))
