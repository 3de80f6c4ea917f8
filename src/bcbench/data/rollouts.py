"""Recorded closed-loop rollouts of a policy (`bcbench eval --record`), stored as a replay buffer.

What a policy saw and did, step by step: the frame and proprioception it observed at each step and the action
executed there, with episode ends and seeds. Not demonstrations (the actions are the policy's, not an expert's):
the correction head trains on them (A2C2 on the base's own states, `CorrectionConfig.rollouts`), with the base's
fresh chunk as its target. One compressed .npz, written atomically; the attributes say which task, policy,
weights and execution made it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.errors import DatasetError
from bcbench.utils.io import atomic_path

FORMAT = "bcbench-rollouts-v1"


@dataclass
class Recorder:
    """Collects each episode's observations and executed actions while it runs (bcbench.evaluation.evaluate)."""

    episodes: dict[int, dict[str, list[Any]]] = field(default_factory=dict)

    def reset(self, ep: int, seed: int, obs: dict[str, np.ndarray]) -> None:
        self.episodes[ep] = {"seed": [seed], "img": [obs["pixels"]], "state": [obs["agent_pos"]], "action": []}

    def acted(self, ep: int, action: np.ndarray) -> None:
        self.episodes[ep]["action"].append(np.asarray(action, dtype=np.float32))

    def observed(self, ep: int, obs: dict[str, np.ndarray]) -> None:
        self.episodes[ep]["img"].append(obs["pixels"])
        self.episodes[ep]["state"].append(obs["agent_pos"])

    def write(self, path: str | Path, attrs: dict[str, Any]) -> Path:
        """Every episode in index order, each step an (observation, action) pair: an episode's last observation,
        after its last action, has none and is left out."""
        eps = [self.episodes[i] for i in sorted(self.episodes) if self.episodes[i]["action"]]
        if not eps:
            raise DatasetError("no episode took a step: nothing to record")
        lengths = [len(e["action"]) for e in eps]
        arrays = {
            "img": np.concatenate([np.stack(e["img"][:n]) for e, n in zip(eps, lengths, strict=True)]),  # (N, H, W, 3)
            "state": np.concatenate([np.stack(e["state"][:n]) for e, n in zip(eps, lengths, strict=True)]),  # (N, S)
            "action": np.concatenate([np.stack(e["action"]) for e in eps]),  # (N, A)
            "episode_ends": np.cumsum(lengths).astype(np.int64),  # (E,) exclusive
            "seeds": np.array([e["seed"][0] for e in eps], dtype=np.int64),  # (E,)
        }
        path = Path(path)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, attrs=np.array(json.dumps({"format": FORMAT, **attrs})), **arrays)
        return path


def rollout_attrs(path: str | Path) -> dict[str, Any]:
    """The attributes a rollout store was written with (task, policy, weights, execution)."""
    with _open(path) as z:
        return json.loads(str(z["attrs"]))


def load_rollouts(path: str | Path) -> ReplayBuffer:
    """A rollout store as a ReplayBuffer: state = the proprioception observed, action = the action executed."""
    with _open(path) as z:
        img, state, action, ends = (np.asarray(z[k]) for k in ("img", "state", "action", "episode_ends"))
    n = len(action)
    if not (len(img) == len(state) == n and len(ends) and ends[-1] == n and np.all(np.diff(ends) > 0)):
        raise DatasetError(f"{path}: arrays of {len(img)}, {len(state)}, {n} steps and episode ends {ends[-3:]} "
                           "do not agree (a damaged rollout store?)")
    return ReplayBuffer(state=state.astype(np.float32), action=action.astype(np.float32), episode_ends=ends,
                        images=img.astype(np.uint8), source=str(path))


def _open(path: str | Path) -> Any:
    path = Path(path)
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not a rollout store ({type(exc).__name__}: {exc})") from None
    if "attrs" not in z or json.loads(str(z["attrs"])).get("format") != FORMAT:
        raise DatasetError(f"{path}: not a {FORMAT} store (write one with `bcbench eval --record`)")
    return z
