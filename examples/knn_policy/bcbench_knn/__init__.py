"""A k-nearest-neighbour chunk policy over the Push-T demonstrations: a bcbench plug-in, and a real baseline.

Non-parametric imitation in the spirit of VINN (Pari et al., 2021, "The Surprising Effectiveness of
Representation Learning for Visual Imitation"), without a learned encoder: every demonstration step becomes a
key (its camera frame, area-downsampled to `size` x `size` RGB in [0, 1], and the agent's position) and a value
(the 16 demonstrated target positions from that step on, the last one repeated past the episode's end). A call
finds the `k` keys nearest to the newest observation (squared distance, the image part averaged per pixel, the
position part in units of the 512-px world times `pos_weight`) and returns their chunks averaged with weights
1 / (distance + eps).

It satisfies bcbench's policy interface (`bcbench.ChunkPolicy`) with nothing from bcbench but its data loader:
    name, obs_horizon, pred_horizon, action_horizon, chunk_start, predict_action_chunk(obs), describe()
"""

from __future__ import annotations

from typing import Any

import numpy as np

PRED_HORIZON = 16


def _downsample(images: np.ndarray, size: int) -> np.ndarray:
    """(N, 96, 96, 3) uint8 -> (N, size * size * 3) float32 in [0, 1] by area averaging (96 must divide by size)."""
    n, h, _, c = images.shape
    f = h // size
    out = np.empty((n, size * size * c), np.float32)
    for s in range(0, n, 2048):  # in blocks: the float copy of all frames would take 2.8 GB
        block = images[s:s + 2048].astype(np.float32).reshape(-1, size, f, size, f, c).mean(axis=(2, 4))
        out[s:s + 2048] = block.reshape(len(block), -1) / 255.0
    return out


class KNNChunkPolicy:
    """Nearest demonstration steps by image and agent position; their future chunks, distance-weighted."""

    name = "knn"
    obs_horizon = 2  # bcbench hands over two frames; the newest is used
    pred_horizon = PRED_HORIZON
    action_horizon = 8
    chunk_start = 0  # the chunk starts at the current step

    def __init__(self, images: np.ndarray, agent_pos: np.ndarray, actions: np.ndarray, episode_ends: np.ndarray,
                 k: int = 5, size: int = 24, pos_weight: float = 1.0) -> None:
        if k < 1 or 96 % size:
            raise ValueError(f"need k >= 1 and a size that divides 96, got k={k}, size={size}")
        self.k, self.size, self.pos_weight = k, size, pos_weight
        self.scale = np.sqrt(pos_weight) / 512.0
        pix = _downsample(images, size) / np.sqrt(size * size * 3)  # (N, D): squared distance = mean per pixel
        self.keys = np.concatenate([pix, agent_pos.astype(np.float32) * self.scale], axis=1)  # (N, D + 2)
        self.sq = (self.keys ** 2).sum(axis=1)  # (N,)
        self.values = self._chunks(actions.astype(np.float32), episode_ends)  # (N, 16, 2)

    @staticmethod
    def _chunks(actions: np.ndarray, episode_ends: np.ndarray) -> np.ndarray:
        out = np.empty((len(actions), PRED_HORIZON, 2), np.float32)
        start = 0
        for end in episode_ends:
            idx = np.arange(start, end)[:, None] + np.arange(PRED_HORIZON)[None, :]  # (L, 16)
            out[start:end] = actions[np.minimum(idx, end - 1)]
            start = end
        return out

    def predict_action_chunk(self, obs: dict[str, Any]) -> np.ndarray:
        image = np.asarray(obs["image"])[:, -1]  # (B, 96, 96, 3) uint8, the newest frame
        pos = np.asarray(obs["agent_pos"], np.float32)[:, -1]  # (B, 2) pixels
        q = np.concatenate([_downsample(image, self.size) / np.sqrt(self.size * self.size * 3),
                            pos * self.scale], axis=1)  # (B, D + 2)
        d2 = np.maximum((q ** 2).sum(1, keepdims=True) - 2 * q @ self.keys.T + self.sq[None], 0.0)  # (B, N)
        near = np.argpartition(d2, self.k - 1, axis=1)[:, :self.k]  # (B, k)
        w = 1.0 / (np.take_along_axis(d2, near, axis=1) + 1e-6)  # (B, k)
        w /= w.sum(axis=1, keepdims=True)
        return np.einsum("bk,bktc->btc", w, self.values[near]).astype(np.float32)  # (B, 16, 2)

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "k": self.k, "size": self.size, "pos_weight": self.pos_weight,
                "demonstration_steps": len(self.keys), "parameters": 0}


def make_policy(k: int = 5, size: int = 24, pos_weight: float = 1.0, data: str | None = None) -> KNNChunkPolicy:
    """The plug-in's factory: loads the Push-T demonstrations (bcbench's data loader; `data` as --data)."""
    from bcbench.data import load_replay_buffer, resolve_dataset

    buf = load_replay_buffer(resolve_dataset(data))
    return KNNChunkPolicy(buf.images, buf.state[:, :2], buf.action, buf.episode_ends, k=k, size=size,
                          pos_weight=pos_weight)
