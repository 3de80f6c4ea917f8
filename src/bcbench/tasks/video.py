"""Rollout videos: MP4 through imageio's bundled ffmpeg, or GIF when ffmpeg is not available."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bcbench.utils.io import atomic_path


class VideoWriter:
    """Collects frames with a caption (step, reward, running score) and writes them at close()."""

    def __init__(self, path: str | Path, label: str = "", fps: int = 10) -> None:
        self.path = Path(path)
        self.label = label
        self.fps = fps
        self.frames: list[np.ndarray] = []
        self._step = 0

    def add(self, frame: np.ndarray, step: int | None, reward: float, score: float) -> None:
        import cv2  # optional: only to draw videos (slow to import)

        self._step = self._step + 1 if step is None else step
        frame = np.ascontiguousarray(frame[..., :3], dtype=np.uint8).copy()
        scale = frame.shape[0] / 256
        lines = [self.label, f"t={self._step}  reward {reward:.2f}  score {score:.2f}"]
        for k, text in enumerate(lines):
            cv2.putText(frame, text, (4, int((14 + 14 * k) * scale)), cv2.FONT_HERSHEY_SIMPLEX, 0.4 * scale,
                        (0, 0, 0), 1, cv2.LINE_AA)
        self.frames.append(frame)

    def close(self) -> str | None:
        """Write the file atomically (temp + rename); returns its path, or None without frames."""
        import imageio.v2 as imageio  # optional: only to write videos

        if not self.frames:
            return None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        frames, self.frames = self.frames, []
        try:
            with atomic_path(self.path) as tmp:
                mp4 = tmp.with_suffix(".mp4")
                imageio.mimwrite(mp4, frames, fps=self.fps, macro_block_size=1)
                mp4.replace(tmp)
            return str(self.path)
        except Exception:  # no ffmpeg: fall back to an animated GIF
            gif = self.path.with_suffix(".gif")
            with atomic_path(gif) as tmp:
                real = tmp.with_suffix(".gif")
                imageio.mimwrite(real, frames, duration=1000 / self.fps, loop=0)
                real.replace(tmp)
            return str(gif)
