"""Training windows over demonstrations, with Diffusion Policy's edge padding.

A window holds obs_horizon observations (image + agent position) and pred_horizon actions that start at
the same time step as the first observation. Windows start from -(obs_horizon - 1) to
L - pred_horizon + (action_horizon - 1) within an episode of length L; indices outside the episode repeat
its first or last step, so a window never crosses an episode boundary (Chi et al., RSS 2023).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bcbench.data.normalizer import MinMaxNormalizer
from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.errors import BCBenchError
from bcbench.protocol import held_out_episodes


def split_episodes(n_episodes: int, val_fraction: float = 0.1, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Seeded episode-level split; returns sorted (train, val) episode indices."""
    if not 0.0 <= val_fraction < 1.0:
        raise BCBenchError(f"val_fraction must be in [0, 1), got {val_fraction}")
    if n_episodes < 2 and val_fraction > 0:
        raise BCBenchError(f"need at least 2 episodes to hold some out, got {n_episodes}")
    perm = np.random.default_rng(seed).permutation(n_episodes)
    n_val = held_out_episodes(n_episodes, val_fraction)
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def window_indices(
    episode_ends: np.ndarray, episodes: np.ndarray, obs_horizon: int, pred_horizon: int, action_horizon: int,
    pad_before: int | None = None,
) -> np.ndarray:
    """(W, pred_horizon) absolute step indices of every window of the given episodes, padding clamped.
    `pad_before` (default obs_horizon - 1) is how far before an episode's first step a window may start: a window
    that holds more frames than its policy observes (the correction head's, obs_horizon + max_age) pads as its base
    did, so that its frame k is the step its base's chunk index k plans for."""
    starts_all = np.concatenate([[0], episode_ends[:-1]])
    pad_before = obs_horizon - 1 if pad_before is None else pad_before
    pad_after = action_horizon - 1
    rows = []
    offsets = np.arange(pred_horizon)
    for e in episodes:
        s, end = int(starts_all[e]), int(episode_ends[e])
        length = end - s
        first, last = -pad_before, length - pred_horizon + pad_after
        if last < first:  # an episode shorter than a window still yields one padded window
            last = first
        local = np.arange(first, last + 1)[:, None] + offsets[None, :]  # (w, pred_horizon)
        rows.append(np.clip(local, 0, length - 1) + s)
    if not rows:
        return np.zeros((0, pred_horizon), dtype=np.int64)
    return np.concatenate(rows).astype(np.int64)


@dataclass
class SequenceDataset:
    """Windows of one split, served as normalised batches.

    Batches: image (B, To, 3, H, W) float32 in [0, 1]; agent_pos (B, To, S) and action (B, Tp, A) in [-1, 1], where
    S is the task's proprioception (the first `state_dim` columns of the buffer's state; Push-T's 5-column state
    holds the agent's position first) and A its action size.
    """

    buffer: ReplayBuffer
    episodes: np.ndarray
    normalizer: MinMaxNormalizer
    obs_horizon: int = 2
    pred_horizon: int = 16
    action_horizon: int = 8
    state_dim: int = 2
    pad_before: int | None = None
    with_steps: bool = False  # batches also carry "steps": each window's absolute buffer steps (B, Tp), int64
    with_images: bool = True  # False: batches carry no "image" (a policy that reads frames itself, by "steps")

    def __post_init__(self) -> None:
        if self.buffer.images is None:
            raise BCBenchError("the sequence dataset needs images: load the replay buffer with images=True")
        if not 1 <= self.obs_horizon <= self.pred_horizon:
            raise BCBenchError(f"need 1 <= obs_horizon <= pred_horizon, got {self.obs_horizon}, {self.pred_horizon}")
        self.indices = window_indices(
            self.buffer.episode_ends, self.episodes, self.obs_horizon, self.pred_horizon, self.action_horizon,
            self.pad_before,
        )

    def __len__(self) -> int:
        return int(self.indices.shape[0])

    def get_batch(self, window_ids: np.ndarray) -> dict[str, np.ndarray]:
        """Gather, normalise and convert a batch of windows (numpy; the trainer moves it to torch)."""
        idx = self.indices[window_ids]  # (B, Tp)
        obs_idx = idx[:, : self.obs_horizon]  # (B, To)
        agent_pos = self.normalizer.normalize("agent_pos", self.buffer.state[obs_idx, : self.state_dim])  # (B, To, S)
        action = self.normalizer.normalize("action", self.buffer.action[idx])  # (B, Tp, A)
        out = {"agent_pos": agent_pos.astype(np.float32), "action": action.astype(np.float32)}
        if self.with_images:
            out = {"image": frames(self.buffer, obs_idx), **out}
        if self.with_steps:
            out["steps"] = idx
        return out

    def __getitem__(self, i: int) -> dict[str, np.ndarray]:
        return {k: v[0] for k, v in self.get_batch(np.array([i])).items()}


def frames(buffer: ReplayBuffer, steps: np.ndarray) -> np.ndarray:
    """The buffer's frames at `steps` (any shape S) as float32 in [0, 1], channels first: (*S, C, H, W)."""
    assert buffer.images is not None
    img = buffer.images[steps]  # (*S, H, W, C) uint8
    img = np.ascontiguousarray(np.moveaxis(img, -1, -3), dtype=np.float32)  # (*S, C, H, W)
    img *= 1.0 / 255.0
    return img


def fit_normalizer(buffer: ReplayBuffer, train_episodes: np.ndarray, state_dim: int = 2) -> MinMaxNormalizer:
    """Min-max statistics of the proprioception (the state's first `state_dim` columns) and the action over the
    training episodes only."""
    steps = np.concatenate([np.arange(buffer.episode_starts[e], buffer.episode_ends[e]) for e in train_episodes])
    return MinMaxNormalizer.fit({"agent_pos": buffer.state[steps, :state_dim], "action": buffer.action[steps]})


def make_datasets(
    buffer: ReplayBuffer, val_fraction: float = 0.1, seed: int = 0, obs_horizon: int = 2,
    pred_horizon: int = 16, action_horizon: int = 8, state_dim: int = 2, demos: int | None = None,
    pad_before: int | None = None, with_steps: bool = False, with_images: bool = True,
    normalizer: MinMaxNormalizer | None = None,
) -> tuple[SequenceDataset, SequenceDataset, MinMaxNormalizer]:
    """Split by episode, fit the normalizer on the training split, build both datasets. `demos` keeps only the
    training split's first N episodes (lowest indices, so smaller counts nest in larger ones) and leaves the
    validation split as it is, so validation losses compare across counts. `normalizer`: use this one instead of
    fitting (data in another model's units: a correction head on its base's rollouts)."""
    train_eps, val_eps = split_episodes(buffer.n_episodes, val_fraction, seed)
    if demos is not None:
        if not 1 <= demos <= len(train_eps):
            raise BCBenchError(f"demos {demos}: the training split has {len(train_eps)} episodes "
                               f"({buffer.n_episodes} in the buffer, {len(val_eps)} held out)")
        train_eps = train_eps[:demos]
    norm = normalizer or fit_normalizer(buffer, train_eps, state_dim)
    kw = {"obs_horizon": obs_horizon, "pred_horizon": pred_horizon, "action_horizon": action_horizon,
          "state_dim": state_dim, "pad_before": pad_before,
          "with_steps": with_steps, "with_images": with_images}
    return SequenceDataset(buffer, train_eps, norm, **kw), SequenceDataset(buffer, val_eps, norm, **kw), norm
