"""scripts/video_strip.py: evaluation videos' frames side by side (results/metaworld-diagnose-pick/failures.png)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import imageio
import imageio.v3 as iio
import numpy as np

_spec = importlib.util.spec_from_file_location("video_strip", Path(__file__).parents[1] / "scripts/video_strip.py")
video_strip = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(video_strip)


def _video(path: Path, n: int, shade: int) -> Path:
    frames = [np.full((32, 48, 3), shade + t, np.uint8) for t in range(n)]  # frame t is (shade + t) grey
    imageio.mimwrite(path, frames, fps=10, macro_block_size=1)
    return path


def test_one_row_per_video_one_column_per_step(tmp_path):
    a, b = _video(tmp_path / "a.mp4", 12, 40), _video(tmp_path / "b.mp4", 12, 160)
    assert video_strip.main([str(tmp_path / "s.png"), str(a), str(b), "--steps", "0,5,11", "--scale", "0.5"]) == 0
    img = iio.imread(tmp_path / "s.png")
    assert img.shape == (32, 72, 3)  # 2 rows of 32 px, 3 columns of 48 px, every 2nd pixel kept
    # the frames are the right ones, in order (a lossy codec moves a flat grey by a few levels at most)
    assert abs(int(img[4, 4, 0]) - 40) <= 3 and abs(int(img[4, 52, 0]) - 51) <= 3
    assert abs(int(img[20, 28, 0]) - 165) <= 3


def test_a_step_past_the_end_or_a_missing_video_is_one_line(tmp_path, capsys):
    a = _video(tmp_path / "a.mp4", 5, 40)
    assert video_strip.main([str(tmp_path / "s.png"), str(a), "--steps", "0,9"]) == 2
    assert "5 frames, no step 9" in capsys.readouterr().err
    assert video_strip.main([str(tmp_path / "s.png"), str(tmp_path / "none.mp4")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no video" in err[0]
    assert not (tmp_path / "s.png").exists()


def test_videos_of_different_sizes_or_an_unreadable_file_are_one_line(tmp_path, capsys):
    a = _video(tmp_path / "a.mp4", 5, 40)
    b = tmp_path / "b.mp4"
    imageio.mimwrite(b, [np.zeros((16, 16, 3), np.uint8)] * 5, fps=10, macro_block_size=1)
    assert video_strip.main([str(tmp_path / "s.png"), str(a), str(b), "--steps", "0,1"]) == 2
    assert "frames of 16x16 px, the first video's differ" in capsys.readouterr().err
    (tmp_path / "c.mp4").write_bytes(b"not a video")
    assert video_strip.main([str(tmp_path / "s.png"), str(tmp_path / "c.mp4")]) == 2
    assert "not a readable video" in capsys.readouterr().err
