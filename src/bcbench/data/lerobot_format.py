"""A task's demonstrations in Hugging Face LeRobot's dataset format v3.0, both ways, with pyarrow and PyAV only.

LeRobot v3.0 (LeRobot 0.6.1, `lerobot/datasets/utils.py`): a folder with
    meta/info.json                                  features, fps, totals, path templates
    meta/stats.json                                 per-feature min, max, mean, std, count, q01 ... q99
    meta/tasks.parquet                              task string (pandas index) -> task_index
    meta/episodes/chunk-000/file-000.parquet        per episode: length, dataset_from_index/to_index, file indices
    data/chunk-000/file-000.parquet                 one row per frame
    videos/observation.image/chunk-000/file-000.mp4 (video datasets) all episodes back to back, AV1
Frames are either PNG bytes inside the parquet (`dtype: image`, lossless) or AV1 video (`dtype: video`,
lossy, as the Hub's `lerobot/pusht`). This module reads both and writes both, PNG by default, so that
`export` then `import` gives back bcbench's arrays bit for bit.

No torch and no torchcodec (which does not load without FFmpeg's shared libraries): frames are decoded with
PyAV's `to_ndarray(format="rgb24")`, the call LeRobot's own PyAV decoder makes.

Mapping for Push-T (bcbench replay buffer <-> LeRobot features):
    data/img        (N, 96, 96, 3) uint8   <-> observation.image (image or video, 96x96x3)
    data/state[:2]  agent position, pixels <-> observation.state (2,)
    data/action     target position        <-> action (2,)
    data/state[2:]  block x, y, angle      <-> bcbench.block_pose (3,)   (not an input of LeRobot policies:
    data/keypoint   (N, 9, 2)              <-> bcbench.keypoint (18,)     only `observation.*` features are;
    data/n_contacts (N, 1)                 <-> bcbench.n_contacts (1,)    LeRobot carries these columns along)
    meta/episode_ends                      <-> meta/episodes dataset_to_index
A LeRobot dataset without the bcbench.* columns (the Hub's lerobot/pusht has agent position and action only)
imports with those arrays zero-filled and named in the zarr's `bcbench_missing` attribute: training on
images works; the simulator replay check, which needs the block pose, refuses it. Each bcbench.* column is
written only where the buffer has it (not for arrays an import zero-filled).

Any other task (a `bcbench.tasks.Task`: MetaWorld's, ...): observation.state is the task's proprioception
(`state_names`, its names in the feature), action its `action_names`, fps its control rate, the frames the
buffer's (H, W, 3), the task string its `instruction`; state columns beyond the proprioception, if a buffer
has any, go in bcbench.state_extra. The data stage sits below the tasks: a task reaches this module as an
argument (`TaskLike`), never by import.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.errors import DatasetError
from bcbench.utils.io import atomic_dir
from bcbench.utils.system import restore_scheduling, scheduling

CODEBASE_VERSION = "v3.0"
FPS = 10  # Push-T's control rate
TASK = "Push the T-shaped block onto the T-shaped target."
IMAGE_KEY = "observation.image"
DATA_FILE = "data/chunk-000/file-000.parquet"
EPISODES_FILE = "meta/episodes/chunk-000/file-000.parquet"
VIDEO_FILE = f"videos/{IMAGE_KEY}/chunk-000/file-000.mp4"
# AV1 as LeRobot 0.6.1 writes it (its rgb_encoder_defaults): SVT-AV1, yuv420p, GOP 2, CRF 30, preset 12.
VIDEO_OPTIONS = {"g": "2", "crf": "30", "preset": "12"}
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
EXTRA = {"bcbench.block_pose": 3, "bcbench.keypoint": 18, "bcbench.n_contacts": 1}  # bcbench's lossless columns
STATE_EXTRA = "bcbench.state_extra"  # another task's state columns beyond its proprioception (any width)
PUSHT_NAMES = {"motors": ["x", "y"]}  # Push-T's observation.state and action names, as exports always wrote them


class TaskLike(Protocol):
    """What the LeRobot format reads of a task (a `bcbench.tasks.Task`)."""

    name: str
    family: str
    image_size: int
    state_names: tuple[str, ...]
    action_names: tuple[str, ...]
    control_hz: float


@dataclass(frozen=True)
class Layout:
    """What a task's LeRobot dataset holds: its rate, task string and the widths and names of its features."""

    pusht: bool
    fps: int | float
    text: str
    state_dim: int
    action_dim: int
    state_names: Any
    action_names: Any
    label: str  # the task in messages
    image_size: int  # the side of the square frames the task reads (what an import checks)


PUSHT = Layout(pusht=True, fps=FPS, text=TASK, state_dim=2, action_dim=2, state_names=PUSHT_NAMES,
               action_names=PUSHT_NAMES, label="Push-T", image_size=96)


def task_text(task: TaskLike) -> str:
    """The task's LeRobot task string: its `instruction`, else one made from its name (`drawer-open` ->
    "Drawer open.")."""
    text = getattr(task, "instruction", "")
    if text:
        return text
    words = task.name.rsplit("/", 1)[-1].replace("-", " ").replace("_", " ").strip()
    return f"{words[:1].upper()}{words[1:]}."


def layout(task: TaskLike | None) -> Layout:
    """The layout of `task`'s datasets; None (or a Push-T task) is Push-T's, exactly as exports always wrote it."""
    if task is None or task.family == "pusht":
        return PUSHT
    hz = float(task.control_hz)
    return Layout(pusht=False, fps=int(hz) if hz.is_integer() else hz, text=task_text(task),
                  state_dim=len(task.state_names), action_dim=len(task.action_names),
                  state_names={"motors": list(task.state_names)}, action_names={"motors": list(task.action_names)},
                  label=f"task {task.name}", image_size=task.image_size)


def _require_backends() -> tuple[Any, Any]:
    try:
        import av  # optional (extra `lerobot`): only the LeRobot format needs it
        import pyarrow
    except ImportError as e:
        raise DatasetError(f"the LeRobot format needs pyarrow and PyAV: pip install 'bcbench[lerobot]' ({e})"
                           ) from None
    return pyarrow, av


# ---------------------------------------------------------------------------------------------- statistics
def _numeric_stats(x: np.ndarray) -> dict[str, list]:
    """LeRobot's per-feature statistics over the frame axis of x (N, D)."""
    x = x.astype(np.float64)
    out = {"min": x.min(0), "max": x.max(0), "mean": x.mean(0), "std": x.std(0)}
    out.update({f"q{round(q * 100):02d}": np.quantile(x, q, axis=0) for q in QUANTILES})
    return {**{k: v.tolist() for k, v in out.items()}, "count": [int(x.shape[0])]}


def _image_stats(images: np.ndarray) -> dict[str, list]:
    """Per-channel statistics of uint8 frames in [0, 1], shaped (3, 1, 1) as LeRobot stores them. Exact:
    from each channel's 256-bin histogram (quantiles by numpy's linear rule on the sorted values)."""
    stats: dict[str, list] = {k: [] for k in ("min", "max", "mean", "std", *(f"q{round(q * 100):02d}"
                                                                              for q in QUANTILES))}
    for c in range(3):
        hist = np.bincount(images[..., c].ravel(), minlength=256).astype(np.float64)
        n = hist.sum()
        levels = np.arange(256) / 255.0
        mean = float((hist * levels).sum() / n)
        stats["mean"].append(mean)
        stats["std"].append(float(np.sqrt((hist * (levels - mean) ** 2).sum() / n)))
        stats["min"].append(float(levels[np.nonzero(hist)[0][0]]))
        stats["max"].append(float(levels[np.nonzero(hist)[0][-1]]))
        cum = np.cumsum(hist)
        for q in QUANTILES:
            pos = (n - 1) * q  # numpy's "linear": between order statistics floor(pos) and ceil(pos)
            lo, hi = (int(np.searchsorted(cum, k, side="right")) for k in (np.floor(pos), np.ceil(pos)))
            frac = pos - np.floor(pos)
            stats[f"q{round(q * 100):02d}"].append(float(levels[lo] + frac * (levels[hi] - levels[lo])))
    shaped = {k: [[[v]] for v in vals] for k, vals in stats.items()}
    return {**shaped, "count": [int(images.shape[0])]}


# ---------------------------------------------------------------------------------------------- export
def _png(img: np.ndarray) -> bytes:
    from PIL import Image  # Pillow, a dependency of matplotlib: PNG is lossless

    bio = io.BytesIO()
    Image.fromarray(img).save(bio, format="PNG")
    return bio.getvalue()


@contextmanager
def _scheduling_kept() -> Iterator[None]:
    """Give the calling thread back the scheduling policy it had. SVT-AV1 (PyAV 18.1's libSvtAv1Enc) switches the
    thread that encodes to SCHED_FIFO at priority 99 where it may (as root) and leaves it there: measured, the
    policy goes from SCHED_OTHER to FIFO 99 at the first frame. Everything the process did next, and every process
    it started, then ran real-time: a test suite whose worker had exported a video starved its other worker (late
    wall-clock steps) and Chromium spun at FIFO 99 for minutes, past its own timeout."""
    was = scheduling()
    try:
        yield
    finally:
        restore_scheduling(was)


def _write_video(path: Path, images: np.ndarray, fps: int | float, av: Any) -> None:
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its configuration to stderr at its default level
    path.parent.mkdir(parents=True, exist_ok=True)
    rate = fps if isinstance(fps, int) else Fraction(fps).limit_denominator(10_000)
    with _scheduling_kept(), av.open(str(path), "w") as out:
        stream = out.add_stream("libsvtav1", rate, options=VIDEO_OPTIONS)
        stream.pix_fmt, stream.width, stream.height = "yuv420p", images.shape[2], images.shape[1]
        for img in images:
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)


def _features(lay: Layout, columns: dict[str, np.ndarray], shape: tuple[int, ...], video: bool) -> dict[str, Any]:
    """info.json's features: the image of `shape` (H, W, 3), then one per frame column, in the columns' order."""
    def vec(n: int, names: Any = None, dtype: str = "float32") -> dict[str, Any]:
        return {"dtype": dtype, "shape": [n], "names": names}

    image: dict[str, Any] = {"dtype": "video" if video else "image", "shape": list(shape),
                             "names": ["height", "width", "channel"]}
    if video:
        image["info"] = {"video.height": shape[0], "video.width": shape[1], "video.codec": "av1",
                         "video.pix_fmt": "yuv420p", "video.fps": lay.fps, "video.channels": 3, "has_audio": False,
                         "video.g": 2, "video.crf": 30, "video.preset": 12, "video.fast_decode": 0,
                         "video.video_backend": "pyav", "video.extra_options": {}, "is_depth_map": False}
    names = {"observation.state": lay.state_names, "action": lay.action_names,
             "bcbench.block_pose": ["x", "y", "angle"]}
    dtypes = {"next.done": "bool", "frame_index": "int64", "episode_index": "int64", "index": "int64",
              "task_index": "int64"}
    return {IMAGE_KEY: image, **{k: vec(1 if v.ndim == 1 else v.shape[1], names.get(k), dtypes.get(k, "float32"))
                                 for k, v in columns.items()}}


def _hf_metadata(features: dict[str, Any]) -> bytes:
    """The `huggingface` schema metadata LeRobot's loader (Hugging Face datasets) reads the columns' types from."""
    hf: dict[str, Any] = {}
    for key, ft in features.items():
        if ft["dtype"] == "video":
            continue
        if ft["dtype"] == "image":
            hf[key] = {"_type": "Image"}
        elif ft["shape"] == [1]:
            hf[key] = {"dtype": ft["dtype"], "_type": "Value"}
        else:
            hf[key] = {"feature": {"dtype": ft["dtype"], "_type": "Value"}, "length": ft["shape"][0],
                       "_type": "List"}
    return json.dumps({"info": {"features": hf}}).encode()


def _extra_columns(buf: ReplayBuffer, lay: Layout) -> dict[str, np.ndarray]:
    """bcbench's lossless columns that the buffer has: Push-T's block pose, or another task's state beyond its
    proprioception; the keypoints and contacts where the buffer holds them (not arrays an import zero-filled)."""
    n, s = buf.n_steps, lay.state_dim
    out: dict[str, np.ndarray] = {}
    if lay.pusht and buf.state.shape[1] >= 5 and "block_pose" not in buf.missing:
        out["bcbench.block_pose"] = buf.state[:, 2:5]
    elif not lay.pusht and buf.state.shape[1] > s:
        out[STATE_EXTRA] = buf.state[:, s:]
    if buf.keypoint is not None and "keypoint" not in buf.missing:
        out["bcbench.keypoint"] = buf.keypoint.reshape(n, -1)
    if buf.n_contacts is not None and "n_contacts" not in buf.missing:
        out["bcbench.n_contacts"] = buf.n_contacts[:, 0]
    return out


def _frame_columns(buf: ReplayBuffer, lay: Layout) -> dict[str, np.ndarray]:
    """Every per-frame column but the image, as arrays (N,) or (N, D): what the data table holds and what
    stats.json summarises."""
    n = buf.n_steps
    episode = np.repeat(np.arange(buf.n_episodes), buf.episode_lengths)
    frame = np.arange(n) - buf.episode_starts[episode]
    done = np.zeros(n, dtype=bool)
    done[buf.episode_ends - 1] = True
    return {"observation.state": buf.state[:, :lay.state_dim], "action": buf.action, **_extra_columns(buf, lay),
            "next.done": done, "timestamp": (frame / lay.fps).astype(np.float32),
            "frame_index": frame.astype(np.int64), "episode_index": episode.astype(np.int64),
            "index": np.arange(n, dtype=np.int64), "task_index": np.zeros(n, dtype=np.int64)}


def _frame_table(buf: ReplayBuffer, columns: dict[str, np.ndarray], features: dict[str, Any], video: bool,
                 pa: Any) -> Any:
    def arrow(a: np.ndarray) -> Any:  # (N,) a plain column; (N, D) a fixed-size list of float32
        if a.ndim == 1:
            return pa.array(a)
        a = np.ascontiguousarray(a, dtype=np.float32)
        return pa.FixedSizeListArray.from_arrays(pa.array(a.ravel()), a.shape[1])

    cols: dict[str, Any] = {}
    if not video:
        assert buf.images is not None
        cols[IMAGE_KEY] = pa.StructArray.from_arrays(
            [pa.array([_png(img) for img in buf.images], pa.binary()),
             pa.array([f"frame-{f:06d}.png" for f in columns["frame_index"]], pa.string())], names=["bytes", "path"])
    cols.update({k: arrow(v) for k, v in columns.items()})
    return pa.table(cols).replace_schema_metadata({b"huggingface": _hf_metadata(features)})


def _episode_table(buf: ReplayBuffer, lay: Layout, video: bool, pa: Any) -> Any:
    starts, ends, e = buf.episode_starts, buf.episode_ends, buf.n_episodes
    cols: dict[str, Any] = {"episode_index": np.arange(e), "tasks": [[lay.text]] * e, "length": buf.episode_lengths,
                            "data/chunk_index": np.zeros(e, np.int64), "data/file_index": np.zeros(e, np.int64),
                            "dataset_from_index": starts, "dataset_to_index": ends}
    if video:  # the episodes lie back to back in one file: each one's time span in it
        cols.update({f"videos/{IMAGE_KEY}/chunk_index": np.zeros(e, np.int64),
                     f"videos/{IMAGE_KEY}/file_index": np.zeros(e, np.int64),
                     f"videos/{IMAGE_KEY}/from_timestamp": starts / lay.fps,
                     f"videos/{IMAGE_KEY}/to_timestamp": ends / lay.fps})
    cols.update({"meta/episodes/chunk_index": np.zeros(e, np.int64),
                 "meta/episodes/file_index": np.zeros(e, np.int64)})
    return pa.table({k: pa.array(v) for k, v in cols.items()})


def _tasks_table(text: str, pa: Any) -> Any:
    table = pa.table({"task_index": pa.array([0], pa.int64()), "task": pa.array([text], pa.string())})
    pandas_meta = {"index_columns": ["task"], "column_indexes": [], "columns": [
        {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64",
         "metadata": None},
        {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": None}],
        "attributes": {}, "creator": {"library": "pyarrow", "version": pa.__version__}, "pandas_version": "2.2.0"}
    return table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})


def _check(buf: ReplayBuffer, lay: Layout) -> None:
    if buf.images is None:
        raise DatasetError("export needs the frames: load the replay buffer with its images")
    if buf.images.ndim != 4 or buf.images.shape[3] != 3 or buf.images.dtype != np.uint8:
        raise DatasetError(f"export needs uint8 (N, H, W, 3) frames, not {buf.images.dtype} {buf.images.shape}")
    if buf.state.shape[1] < lay.state_dim or buf.action.shape[1] != lay.action_dim:
        raise DatasetError(f"{buf.source or 'the buffer'}: state {buf.state.shape[1:]} / action {buf.action.shape[1:]}"
                           f" do not fit {lay.label} ({lay.state_dim} state values, {lay.action_dim} action values)")


def export_lerobot(buf: ReplayBuffer, out: str | Path, *, video: bool = False, force: bool = False,
                   task: TaskLike | None = None) -> dict[str, Any]:
    """Write `buf`, the demonstrations of `task` (None: Push-T), as a LeRobot v3.0 dataset at `out` (PNG frames
    in the parquet, or AV1 video with `video`). Atomic: written into a temporary folder beside `out`, renamed into
    place when complete."""
    pa, av = _require_backends()
    import pyarrow.parquet as pq

    lay = layout(task)
    _check(buf, lay)
    assert buf.images is not None
    out = Path(out)
    columns = _frame_columns(buf, lay)
    features = _features(lay, columns, buf.images.shape[1:], video)
    with atomic_dir(out, force) as tmp:
        tables = {DATA_FILE: _frame_table(buf, columns, features, video, pa),
                  EPISODES_FILE: _episode_table(buf, lay, video, pa), "meta/tasks.parquet": _tasks_table(lay.text, pa)}
        for rel, table in tables.items():
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            pq.write_table(table, tmp / rel)
        if video:
            _write_video(tmp / VIDEO_FILE, buf.images, lay.fps, av)
        numeric = {k: v if v.ndim == 2 else v[:, None] for k, v in columns.items() if k != "next.done"}
        stats = {IMAGE_KEY: _image_stats(buf.images), **{k: _numeric_stats(v) for k, v in numeric.items()}}
        (tmp / "meta/info.json").write_text(json.dumps(_info_json(buf, lay, features, video), indent=4))
        (tmp / "meta/stats.json").write_text(json.dumps(stats, indent=4))
    return {"path": str(out), "episodes": buf.n_episodes, "frames": buf.n_steps,
            "frames_stored_as": "AV1 video (lossy)" if video else "PNG in parquet (lossless)"}


def _info_json(buf: ReplayBuffer, lay: Layout, features: dict[str, Any], video: bool) -> dict[str, Any]:
    return {"codebase_version": CODEBASE_VERSION, "fps": lay.fps, "features": features,
            "total_episodes": buf.n_episodes, "total_frames": buf.n_steps, "total_tasks": 1,
            "chunks_size": 1000, "data_files_size_in_mb": 100, "video_files_size_in_mb": 200,
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
            "video_path": ("videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
                           if video else None),
            "robot_type": None, "splits": {"train": f"0:{buf.n_episodes}"}}
