"""`bcbench data import --from lerobot DIR`: a LeRobot v3.0 Push-T dataset into bcbench's replay buffer.

Reads parquet with pyarrow and AV1 video with PyAV (frames matched to rows by timestamp, within LeRobot's
own tolerance of 1e-4 s); PNG frames stored in the parquet are decoded with Pillow. The format and the
feature mapping are described in `bcbench.data.lerobot_format`. Every problem is one `DatasetError` line.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from bcbench.data.lerobot_format import CODEBASE_VERSION, EXTRA, FPS, IMAGE_KEY, _require_backends
from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.errors import DatasetError

TOLERANCE_S = 1e-4  # LeRobot's default tolerance between a row's timestamp and its video frame
REQUIRED = {"observation.state": 2, "action": 2}  # feature -> numbers per frame
ROW_COLUMNS = ("index", "episode_index", "frame_index", "timestamp")


def _info(src: Path) -> dict[str, Any]:
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
    image = features.get(IMAGE_KEY)
    if image is None:
        raise DatasetError(f"{src}: no feature '{IMAGE_KEY}' in meta/info.json (Push-T's camera)")
    if image.get("dtype") not in ("image", "video") or list(image.get("shape", [])) != [96, 96, 3]:
        raise DatasetError(f"{src}: feature '{IMAGE_KEY}' is {image.get('dtype')} {image.get('shape')}, expected an "
                           "image or video of shape [96, 96, 3]")
    for key, width in {**REQUIRED, **EXTRA}.items():
        if key in REQUIRED and key not in features:
            raise DatasetError(f"{src}: no feature '{key}' in meta/info.json (Push-T needs it)")
        if key in features and list(features[key].get("shape", [])) != [width]:
            raise DatasetError(f"{src}: feature '{key}' has shape {features[key].get('shape')}, expected [{width}]")
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


def _png_frames(table: Any, src: Path) -> np.ndarray:
    from PIL import Image

    cells = table.column(IMAGE_KEY).to_pylist()
    out = np.empty((len(cells), 96, 96, 3), dtype=np.uint8)
    for i, cell in enumerate(cells):
        try:
            img = np.asarray(Image.open(io.BytesIO(cell["bytes"])).convert("RGB"))
        except Exception as e:
            raise DatasetError(f"{src}: frame {i} of '{IMAGE_KEY}' is not a readable image ({e})") from None
        if img.shape != (96, 96, 3):
            raise DatasetError(f"{src}: frame {i} of '{IMAGE_KEY}' is {img.shape}, expected (96, 96, 3)")
        out[i] = img
    return out


def _decode_video(path: Path) -> tuple[np.ndarray, list[np.ndarray]]:
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
    if not frames or frames[0].shape != (96, 96, 3):
        raise DatasetError(f"{path}: no 96x96 RGB frames")
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
                  timestamps: np.ndarray) -> np.ndarray:
    """The frame of each row (rows in episode order), from the episodes' spans in their video files."""
    template = info.get("video_path")
    if not template:
        raise DatasetError(f"{src}: '{IMAGE_KEY}' is a video feature but meta/info.json has no video_path")
    prefix = f"videos/{IMAGE_KEY}/"
    for col in ("chunk_index", "file_index", "from_timestamp"):
        if prefix + col not in episodes:
            raise DatasetError(f"{src}: meta/episodes lacks column '{prefix + col}'")
    out = np.empty((len(timestamps), 96, 96, 3), dtype=np.uint8)
    cache: dict[Path, tuple[np.ndarray, list[np.ndarray]]] = {}
    row = 0
    for e in order:
        path = src / template.format(video_key=IMAGE_KEY, chunk_index=int(episodes[prefix + "chunk_index"][e]),
                                     file_index=int(episodes[prefix + "file_index"][e]))
        if not path.is_file():
            raise DatasetError(f"{src}: missing video file {path.relative_to(src)}")
        if path not in cache:
            cache = {path: _decode_video(path)}  # episodes come file by file: keep one file decoded
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


def import_lerobot(src: str | Path) -> ReplayBuffer:
    """Read a LeRobot v3.0 Push-T dataset; the episodes in episode_index order, frames in frame order."""
    _require_backends()
    src = Path(src)
    if not src.is_dir():
        raise DatasetError(f"{src}: no such folder")
    info = _info(src)
    features = info["features"]
    video = features[IMAGE_KEY]["dtype"] == "video"
    extra = [k for k in EXTRA if k in features]
    columns = [*ROW_COLUMNS, *REQUIRED, *extra, *([] if video else [IMAGE_KEY])]
    table = _read_parquets(src / "data", columns)
    ep_table = _read_parquets(src / "meta" / "episodes")
    need = ["episode_index", "length", "dataset_from_index", "dataset_to_index"]
    if [c for c in need if c not in ep_table.column_names]:
        raise DatasetError(f"{src}: meta/episodes lacks one of {', '.join(need)}")
    episodes = {c: np.asarray(ep_table.column(c).to_numpy(zero_copy_only=False)) for c in ep_table.column_names
                if not c.startswith("stats/") and c != "tasks"}
    order = np.argsort(episodes["episode_index"], kind="stable")
    index = table.column("index").to_numpy()
    position = {int(v): i for i, v in enumerate(index)}
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
    take = np.concatenate(rows)
    table = table.take(take)
    ep_of_row = np.repeat(episodes["episode_index"][order], episodes["length"][order])
    if not np.array_equal(table.column("episode_index").to_numpy(), ep_of_row):
        raise DatasetError(f"{src}: the data rows' episode_index disagrees with meta/episodes")
    lengths = episodes["length"][order].astype(np.int64)
    frame_expect = np.concatenate([np.arange(n) for n in lengths])
    if not np.array_equal(table.column("frame_index").to_numpy(), frame_expect):
        raise DatasetError(f"{src}: frame_index does not run 0 .. length-1 within every episode")
    n = len(table)
    timestamps = table.column("timestamp").to_numpy().astype(np.float64)
    images = (_video_frames(src, info, episodes, order, timestamps) if video else _png_frames(table, src))
    def extra_or_zeros(key: str) -> np.ndarray:
        return _vectors(table, key, EXTRA[key], src) if key in extra else np.zeros((n, EXTRA[key]), np.float32)

    block, contacts = extra_or_zeros("bcbench.block_pose"), extra_or_zeros("bcbench.n_contacts")
    keypoint = extra_or_zeros("bcbench.keypoint").reshape(n, 9, 2)
    if int(info.get("fps", FPS)) != FPS:
        raise DatasetError(f"{src}: recorded at {info.get('fps')} fps; Push-T runs at {FPS}")
    return ReplayBuffer(
        state=np.concatenate([_vectors(table, "observation.state", 2, src), block], axis=1),
        action=_vectors(table, "action", 2, src), episode_ends=np.cumsum(lengths), images=images,
        keypoint=keypoint, n_contacts=contacts, source=str(src),
        missing=tuple(k.removeprefix("bcbench.") for k in EXTRA if k not in extra))
