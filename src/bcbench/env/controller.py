"""Receding-horizon execution of action chunks, shared by every policy.

The controller, not the policy, keeps each environment's observation history (the last obs_horizon
observations; at reset the first one is repeated, as in Diffusion Policy) and a queue of actions. When an
environment's queue runs dry, it is re-planned: the policy is called once for all such environments
(batched) and the next action_horizon actions of each chunk are queued.

Each environment also owns its noise stream: a torch.Generator seeded from (the policy's noise seed, the
episode's seed), handed to the policy with the batch (`obs["generators"]`, one per row). A stochastic
policy draws row i's noise from it, so an episode's actions depend on its own seed only, never on which
other episodes are batched with it, on --episodes or on --workers.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from typing import Any

import numpy as np
import torch

from bcbench.errors import BCBenchError


def episode_generator(policy_seed: int, episode_seed: int) -> torch.Generator:
    """The noise stream of one episode: a pure function of (policy seed, episode seed)."""
    seed = int(np.random.SeedSequence([int(policy_seed), int(episode_seed)]).generate_state(1, np.uint64)[0])
    return torch.Generator().manual_seed(seed)


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
        self._noise: dict[int, torch.Generator] = {}
        self.n_calls = 0  # batched policy calls
        self.n_plans = 0  # chunks planned (sum of batch sizes)

    def reset(self, env_id: int, obs: dict[str, np.ndarray], seed: int | None = None) -> None:
        """Start environment `env_id` at `obs`; its noise stream comes from `seed` (default: env_id)."""
        self._history[env_id] = deque([obs] * self.obs_horizon, maxlen=self.obs_horizon)
        self._queue[env_id] = deque()
        policy_seed = getattr(self.policy, "noise_seed", 0)
        self._noise[env_id] = episode_generator(policy_seed, env_id if seed is None else seed)

    def observe(self, env_id: int, obs: dict[str, np.ndarray]) -> None:
        self._history[env_id].append(obs)

    def drop(self, env_id: int) -> None:
        self._history.pop(env_id, None)
        self._queue.pop(env_id, None)
        self._noise.pop(env_id, None)

    def stacked_obs(self, env_ids: list[int]) -> dict[str, Any]:
        """Batch of histories: image (B, To, H, W, 3) uint8, agent_pos (B, To, 2) float32, generators [B]."""
        image = np.stack([np.stack([o["pixels"] for o in self._history[i]]) for i in env_ids])
        agent_pos = np.stack([np.stack([o["agent_pos"] for o in self._history[i]]) for i in env_ids])
        return {"image": image, "agent_pos": agent_pos.astype(np.float32),
                "generators": [self._noise[i] for i in env_ids]}

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
