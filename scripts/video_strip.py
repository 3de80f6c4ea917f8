"""Frames of evaluation videos side by side, one row per video: what a failure looks like, where a reader would
rather look than read (`bcbench eval --video N` writes the videos; their overlay names the seed and step).

    python scripts/video_strip.py OUT.png VIDEO.mp4 [VIDEO.mp4 ...] [--steps 0,15,25,35,45,60,99] [--scale 0.5]

Bad input (a missing video, a step past a video's end, no video) is one line on stderr and exit 2; the PNG is
written atomically.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from bcbench.utils.io import atomic_path


def strip(videos: list[Path], steps: list[int], scale: float) -> np.ndarray:
    """(rows * H, len(steps) * W, 3) uint8: each video's frames at `steps`, left to right, scaled by `scale`."""
    rows, first = [], None
    for v in videos:
        try:
            frames = iio.imread(v)  # (T, H, W, 3)
        except OSError as e:
            raise ValueError(f"{v}: not a readable video ({e})") from None
        late = [s for s in steps if s >= len(frames)]
        if late:
            raise ValueError(f"{v}: {len(frames)} frames, no step {late[0]}")
        first = first or frames.shape[1:]  # (H, W, 3) of the first video: every row must match it
        if frames.shape[1:] != first:
            raise ValueError(f"{v}: frames of {frames.shape[2]}x{frames.shape[1]} px, the first video's differ")
        rows.append(np.concatenate([frames[s] for s in steps], axis=1))
    out = np.concatenate(rows, axis=0)
    k = max(1, round(1 / scale))  # integer subsampling: no resampling library needed, no blur added
    return np.ascontiguousarray(out[::k, ::k])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("out", type=Path)
    p.add_argument("videos", type=Path, nargs="+")
    p.add_argument("--steps", default="0,15,25,35,45,60,99", help="frame indices (step t is frame t)")
    p.add_argument("--scale", type=float, default=0.5, help="1, 0.5, 0.33, ...: keep every round(1/scale)-th pixel")
    a = p.parse_args(argv)
    try:
        steps = [int(s) for s in a.steps.split(",")]
        if a.scale <= 0 or a.scale > 1 or min(steps) < 0:
            raise ValueError("--scale is in (0, 1] and --steps are frame indices >= 0")
        missing = [v for v in a.videos if not v.is_file()]
        if missing:
            raise ValueError(f"no video {missing[0]}")
        image = strip(a.videos, steps, a.scale)
    except ValueError as e:
        print(f"video_strip: {e}", file=sys.stderr)
        return 2
    with atomic_path(a.out) as tmp:
        iio.imwrite(tmp, image, extension=".png")
    print(f"{a.out}: {len(a.videos)} video(s) x {len(steps)} frames, {image.shape[1]}x{image.shape[0]} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
