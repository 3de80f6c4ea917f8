"""Receding-horizon execution of action chunks, shared by every policy.

The controller, not the policy, keeps each environment's observation history (the last obs_horizon
observations; at reset the first one is repeated, as in Diffusion Policy) and a queue of actions. When an
environment's queue runs dry, it is re-planned: the policy is called once for all such environments
(batched) and the next action_horizon actions of each chunk are queued.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from typing import Any

import numpy as np

from bcbench.errors import BCBenchError


class ChunkedController:
    """Observation history and action queues for a set of environments keyed by id."""

    def __init__(self, policy: Any, action_horizon: int | None = None) -> None:
        self.policy = policy
        self.obs_horizon = int(policy.obs_horizon)
        self.pred_horizon = int(policy.pred_horizon)
        self.action_horizon = int(action_horizon or policy.action_horizon)
        # Index in the chunk of the action for the *current* step. Policies trained on Diffusion Policy's
        # windows predict from the oldest observation on, so the current step is at obs_horizon - 1.
        self.chunk_start = int(getattr(policy, "chunk_start", 0))
        if self.chunk_start + self.action_horizon > self.pred_horizon:
            raise BCBenchError(
                f"action_horizon {self.action_horizon} from chunk index {self.chunk_start} exceeds the "
                f"policy's pred_horizon {self.pred_horizon}"
            )
        self._history: dict[int, deque[dict[str, np.ndarray]]] = {}
        self._queue: dict[int, deque[np.ndarray]] = {}
        self.n_calls = 0  # batched policy calls
        self.n_plans = 0  # chunks planned (sum of batch sizes)

    def reset(self, env_id: int, obs: dict[str, np.ndarray]) -> None:
        self._history[env_id] = deque([obs] * self.obs_horizon, maxlen=self.obs_horizon)
        self._queue[env_id] = deque()

    def observe(self, env_id: int, obs: dict[str, np.ndarray]) -> None:
        self._history[env_id].append(obs)

    def drop(self, env_id: int) -> None:
        self._history.pop(env_id, None)
        self._queue.pop(env_id, None)

    def stacked_obs(self, env_ids: list[int]) -> dict[str, np.ndarray]:
        """Batch of histories: image (B, To, H, W, 3) uint8, agent_pos (B, To, 2) float32."""
        image = np.stack([np.stack([o["pixels"] for o in self._history[i]]) for i in env_ids])
        agent_pos = np.stack([np.stack([o["agent_pos"] for o in self._history[i]]) for i in env_ids])
        return {"image": image, "agent_pos": agent_pos.astype(np.float32)}

    def act(self, env_ids: Iterable[int]) -> dict[int, np.ndarray]:
        """One action per environment; re-plans (one batched call) those whose queue is empty."""
        env_ids = list(env_ids)
        need = [i for i in env_ids if not self._queue[i]]
        if need:
            chunks = np.asarray(self.policy.predict_action_chunk(self.stacked_obs(need)))  # (B, Tp, 2)
            if chunks.shape != (len(need), self.pred_horizon, 2):
                raise BCBenchError(
                    f"policy returned a chunk of shape {chunks.shape}, expected ({len(need)}, {self.pred_horizon}, 2)"
                )
            if not np.isfinite(chunks).all():
                raise BCBenchError("policy returned NaN or infinite actions")
            self.n_calls += 1
            self.n_plans += len(need)
            for i, chunk in zip(need, chunks, strict=True):
                self._queue[i].extend(chunk[self.chunk_start : self.chunk_start + self.action_horizon])
        return {i: self._queue[i].popleft() for i in env_ids}
