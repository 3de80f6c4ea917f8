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
        return _write(path, arrays, attrs)


def rollout_attrs(path: str | Path) -> dict[str, Any]:
    """The attributes a rollout store was written with (task, policy, weights, execution)."""
    with _open(path) as z:
        return json.loads(str(z["attrs"]))


def load_rollouts(path: str | Path) -> ReplayBuffer:
    """A rollout store as a ReplayBuffer: state = the proprioception observed, action = the action executed."""
    a = _arrays(path)
    return ReplayBuffer(state=a["state"].astype(np.float32), action=a["action"].astype(np.float32),
                        episode_ends=a["episode_ends"], images=a["img"].astype(np.uint8), source=str(path))


def join_rollouts(out: str | Path, paths: list[str | Path]) -> dict[str, np.ndarray]:
    """One store of several of one base (a DAgger round's union): the arrays concatenated in the order given, as
    recorded (dtypes kept), episode ends shifted; the first store's attributes with `joined_from` listing every
    input's. Stores of other base weights or another task are refused in one line."""
    attrs = [rollout_attrs(p) for p in paths]
    for what, of in (("task", lambda a: a.get("task")),
                     ("weights", lambda a: a.get("policy", {}).get("weights_sha256"))):
        seen = {json.dumps(of(a)) for a in attrs}
        if len(seen) != 1:
            raise DatasetError(f"the stores differ in {what} ({', '.join(sorted(seen))}): join one base's rollouts")
    stores = [_arrays(p) for p in paths]
    offsets = np.cumsum([0] + [len(z["action"]) for z in stores[:-1]])
    arrays = {k: np.concatenate([z[k] for z in stores]) for k in ("img", "state", "action", "seeds")}
    arrays["episode_ends"] = np.concatenate([z["episode_ends"] + o for z, o in zip(stores, offsets, strict=True)])
    meta = {k: v for k, v in attrs[0].items() if k != "format"}
    meta["joined_from"] = [{"path": str(p), "attrs": a} for p, a in zip(paths, attrs, strict=True)]
    _write(out, arrays, meta)
    return arrays


def _write(path: str | Path, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, attrs=np.array(json.dumps({"format": FORMAT, **attrs})), **arrays)
    return path


def _arrays(path: str | Path) -> dict[str, np.ndarray]:
    """A store's arrays as recorded, checked to agree (a damaged store is refused in one line)."""
    with _open(path) as z:
        a = {k: np.asarray(z[k]) for k in ("img", "state", "action", "episode_ends", "seeds")}
    n, ends = len(a["action"]), a["episode_ends"]
    if not (len(a["img"]) == len(a["state"]) == n and len(ends) and ends[-1] == n and np.all(np.diff(ends) > 0)):
        raise DatasetError(f"{path}: arrays of {len(a['img'])}, {len(a['state'])}, {n} steps and episode ends "
                           f"{ends[-3:]} do not agree (a damaged rollout store?)")
    return a


def _open(path: str | Path) -> Any:
    path = Path(path)
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not a rollout store ({type(exc).__name__}: {exc})") from None
    if "attrs" not in z or json.loads(str(z["attrs"])).get("format") != FORMAT:
        raise DatasetError(f"{path}: not a {FORMAT} store (write one with `bcbench eval --record`)")
    return z
