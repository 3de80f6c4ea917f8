"""Receding-horizon execution of action chunks, shared by every policy.

The controller, not the policy, keeps each environment's observation history (the last obs_horizon
observations; at reset the first one is repeated, as in Diffusion Policy) and a queue of actions. When an
environment's queue runs dry, it is re-planned: the policy is called once for all such environments
(batched) and the next action_horizon actions of each chunk are queued.

Execution under latency (`execution`): a call whose latency is d control steps (`delay(env_id)`)
- `sync`: the world waits for the policy (d has no effect): the simulators' usual assumption;
- `blocking`: the world does not wait: the agent holds its last commanded target for d steps while the
  policy computes, then runs the new chunk from its start;
- `async`: the next chunk is asked for when the queue falls to d actions (the threshold; a chunk arrives
  just in time), computed from the observation of that moment, while the agent runs the queue's last
  actions; on arrival its first d actions, now in the past, are skipped and it replaces the queue. If the
  queue runs dry first, the agent holds its last target. How many actions of each chunk run before the next
  one replaces it is the execution horizon s (Real-Time Chunking's, Black et al. 2025, Sec. 3): by default
  the action horizon minus d (the chunk's actions up to its action horizon, the first d skipped); with
  `execution_horizon` s, the chunk supplies s actions from index chunk_start + d, so requests come every s
  steps (Diffusion Policy's latency experiment, its Fig. 6: first d dropped, 8 executed, is s = 8).
With d = 0 both give exactly the sync result. The controller counts the d of every call (`delays`).

Strategies (`strategy`, bcbench.evaluation.strategies) decide what is done with consecutive chunks, in every
execution mode. Each received chunk keeps its origin (the step at which its index chunk_start executes: the
request's step, or its arrival under blocking). At a request the chunk executing is aligned to the new chunk's
indices (the target) with Real-Time Chunking's soft mask: 1 for the actions that execute before the new chunk
arrives (the past ones and the d of the delay: the frozen prefix), decaying over the rest of the overlap. RTC,
BID and the prefix strategy read them; ensembling averages, at each step, every received chunk's action for it.

Per-step hook: a strategy with one (`Strategy.per_step`: A2C2's correction head) is called once per step, batched
over the environments that take an action from their queue, with their current observation windows, those planned
actions, the age of the chunk they come from (steps since its observation) and their index in it; what it returns
is executed (and held, should the queue run dry). Environments holding their last target are not corrected.

Each environment also owns its noise stream: a torch.Generator seeded from (the policy's noise seed, the
episode's seed), handed to the policy with the batch (`obs["generators"]`, one per row). A stochastic
policy draws row i's noise from it, so an episode's actions depend on its own seed only, never on which
other episodes are batched with it, on --episodes or on --workers.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from bcbench.errors import BCBenchError
from bcbench.evaluation.config import EXECUTIONS, StrategyConfig
from bcbench.evaluation.strategies import Strategy, ensemble_action, prefix_weights
from bcbench.interface import ChunkPolicy, SeededPolicy
from bcbench.tasks import Task, get_task


def episode_generator(policy_seed: int, episode_seed: int) -> torch.Generator:
    """The noise stream of one episode: a pure function of (policy seed, episode seed)."""
    seed = int(np.random.SeedSequence([int(policy_seed), int(episode_seed)]).generate_state(1, np.uint64)[0])
    return torch.Generator().manual_seed(seed)


WEAK_STREAM = 1  # BID's weak policy draws from its own streams, so the strong policy's are those of naive


@dataclass
class _Chunk:
    """A chunk the agent received (or will, at `arrival`): index chunk_start executes at step `origin`."""

    origin: int
    arrival: int
    chunk: np.ndarray  # (Tp, A) in the task's units
    actions: list[np.ndarray]  # what it puts in the queue
    observed: int = 0  # the step of the observation it was computed from (its age is counted from here)


def async_actions_needed(chunk_start: int, d: int, s: int | None) -> int:
    """How many actions of a chunk async execution needs after a delay of d steps: the current step's index,
    the d that pass before the chunk arrives, then s to execute (at least one; Real-Time Chunking: s <= H - d)."""
    return chunk_start + d + (s or 1)


def actions_executed(action_horizon: int, d: int, s: int | None) -> int:
    """Actions of each async chunk executed before the next one is asked for: the execution horizon s where one is
    given, else what the action horizon leaves after the delay, at least one."""
    return s if s is not None else max(action_horizon - d, 1)


class ChunkedController:
    """Observation history and action queues for a set of environments keyed by id."""

    def __init__(self, policy: ChunkPolicy, action_horizon: int | None = None, execution: str = "sync",
                 delay: Callable[[int], int] | None = None, execution_horizon: int | None = None,
                 strategy: Strategy | None = None, task: Task | None = None) -> None:
        if execution not in EXECUTIONS:
            raise BCBenchError(f"--execution must be one of {', '.join(EXECUTIONS)}, got '{execution}'")
        self.policy, self.execution = policy, execution
        self.task = task or get_task()  # the action's size and what holds the robot still (Push-T by default)
        self.action_dim = self.task.action_dim
        self.delay = delay or (lambda env_id: 0)  # control steps a call started now takes (0: none)
        self.obs_horizon = int(policy.obs_horizon)
        self.pred_horizon = int(policy.pred_horizon)
        self.action_horizon = int(action_horizon or policy.action_horizon)
        # Index in the chunk of the action for the *current* step. Policies trained on Diffusion Policy's
        # windows predict from the oldest observation on, so the current step is at obs_horizon - 1.
        self.chunk_start = int(policy.chunk_start)
        if self.chunk_start + self.action_horizon > self.pred_horizon:
            raise BCBenchError(
                f"action_horizon {self.action_horizon} from chunk index {self.chunk_start} exceeds the "
                f"policy's pred_horizon {self.pred_horizon}"
            )
        self.execution_horizon = execution_horizon  # async only (s); None: action_horizon - d
        if execution_horizon is not None and (execution != "async" or execution_horizon < 1):
            raise BCBenchError("an execution horizon goes with async execution and must be >= 1")
        self._history: dict[int, deque[dict[str, np.ndarray]]] = {}
        self._queue: dict[int, deque[np.ndarray]] = {}
        self._noise: dict[int, torch.Generator] = {}
        self.strategy = strategy or Strategy(StrategyConfig(), policy)
        self._weak_noise: dict[int, torch.Generator] = {}
        self._pending: dict[int, _Chunk | None] = {}
        self._received: dict[int, list[_Chunk]] = {}  # chunks that still predict a step to come, oldest first
        self._next_delay: dict[int, int] = {}  # async: the d of the env's next call, drawn in advance
        self._step: dict[int, int] = {}
        self._last: dict[int, np.ndarray] = {}  # the last commanded target (held while waiting)
        self.n_calls = 0  # batched policy calls
        self.n_plans = 0  # chunks planned (sum of batch sizes)
        self.delays: list[int] = []  # d of every planned chunk

    def reset(self, env_id: int, obs: dict[str, np.ndarray], seed: int | None = None) -> None:
        """Start environment `env_id` at `obs`; its noise stream comes from `seed` (default: env_id)."""
        self._history[env_id] = deque([obs] * self.obs_horizon, maxlen=self.obs_horizon)
        self._queue[env_id] = deque()
        policy_seed = self.policy.noise_seed if isinstance(self.policy, SeededPolicy) else 0
        self._noise[env_id] = episode_generator(policy_seed, env_id if seed is None else seed)
        if self.strategy.weak is not None:
            self._weak_noise[env_id] = episode_generator(policy_seed + WEAK_STREAM, env_id if seed is None else seed)
        self._pending[env_id], self._step[env_id], self._received[env_id] = None, 0, []
        self._last[env_id] = self.task.hold_action(obs)  # before any command: stay put
        if self.execution == "async":
            self._next_delay[env_id] = self._checked_delay(env_id)

    def observe(self, env_id: int, obs: dict[str, np.ndarray]) -> None:
        self._history[env_id].append(obs)

    def drop(self, env_id: int) -> None:
        self._history.pop(env_id, None)
        self._queue.pop(env_id, None)
        for d in (self._noise, self._weak_noise, self._pending, self._next_delay, self._step, self._last,
                  self._received):
            d.pop(env_id, None)

    def stacked_obs(self, env_ids: list[int]) -> dict[str, Any]:
        """Batch of histories: image (B, To, H, W, 3) uint8, agent_pos (B, To, S) float32, generators [B]."""
        image = np.stack([np.stack([o["pixels"] for o in self._history[i]]) for i in env_ids])
        agent_pos = np.stack([np.stack([o["agent_pos"] for o in self._history[i]]) for i in env_ids])
        return {"image": image, "agent_pos": agent_pos.astype(np.float32),
                "generators": [self._noise[i] for i in env_ids]}

    def _checked_delay(self, env_id: int) -> int:
        d = int(self.delay(env_id))
        if d < 0:
            raise BCBenchError(f"a delay of {d} steps is negative")
        if self.execution == "async" and async_actions_needed(self.chunk_start, d, None) > self.pred_horizon:
            raise BCBenchError(f"async execution with a delay of {d} steps: the chunk of {self.pred_horizon} actions "
                               f"(the current one at index {self.chunk_start}) would be entirely in the past")
        s, need = self.execution_horizon, async_actions_needed(self.chunk_start, d, self.execution_horizon)
        if self.execution == "async" and s is not None and need > self.pred_horizon:
            raise BCBenchError(f"execution horizon {s} after a delay of {d} steps needs {need} "
                               f"actions of a chunk of {self.pred_horizon} (s <= H - d, as Real-Time Chunking)")
        return d

    def _target(self, i: int, origin: int, frozen_end: int) -> tuple[np.ndarray, np.ndarray]:
        """The chunk executing, aligned to a new chunk of this origin (Tp, A), and RTC's soft mask over it (Tp,)."""
        tp = self.pred_horizon
        target, weights = np.zeros((tp, self.action_dim), np.float32), np.zeros(tp, np.float32)
        if self._received[i]:
            prev = self._received[i][-1]
            shift = origin - prev.origin  # new index k is the previous chunk's k + shift
            if 0 <= shift < tp:
                target[: tp - shift] = prev.chunk[shift:]
                weights = prefix_weights(tp, frozen_end, tp - shift)
        # The frozen prefix is what the agent will execute before the new chunk arrives: the queue's actions and,
        # should it run dry first (s < d), its last target held (RTC's s >= d avoids that; bcbench allows it).
        queued = list(self._queue[i]) or [self._last[i]]
        for j, k in enumerate(range(self.chunk_start, frozen_end)):
            target[k] = queued[min(j, len(queued) - 1)]
            weights[k] = 1.0
        return target, weights

    def _plan(self, env_ids: list[int], delays: list[int]) -> np.ndarray:
        """One batched request for these environments under the strategy: (B, Tp, A) chunks."""
        obs = self.stacked_obs(env_ids)
        target = weights = weak = None
        if self.strategy.uses_target:
            pairs = []
            for i, d in zip(env_ids, delays, strict=True):
                t, origin = self._step[i], self._origin(i, d)
                pairs.append(self._target(i, origin, self.chunk_start + t + d - origin))
            target, weights = np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])
            weak = [self._weak_noise[i] for i in env_ids] if self.strategy.weak is not None else None
        chunks = self.strategy.request(obs, target, weights, weak)  # (B, Tp, A)
        want = (len(env_ids), self.pred_horizon, self.action_dim)
        if chunks.shape != want:
            raise BCBenchError(f"policy returned a chunk of shape {chunks.shape}, expected {want}")
        if not np.isfinite(chunks).all():
            raise BCBenchError("policy returned NaN or infinite actions")
        self.n_calls += 1
        self.n_plans += len(env_ids)
        return chunks

    def _origin(self, i: int, d: int) -> int:
        """The step at which a chunk requested now with delay d executes its index chunk_start."""
        return self._step[i] + (d if self.execution == "blocking" else 0)

    def _delay_now(self, i: int) -> int:
        """d of the call that env i makes now (async drew it in advance, when its previous chunk was planned)."""
        if self.execution == "sync":
            return 0
        return self._next_delay[i] if self.execution == "async" else self._checked_delay(i)

    def _wants_plan(self, i: int) -> bool:
        if self.execution == "sync":
            return not self._queue[i]
        if self._pending[i] is not None:
            return False
        if self.execution == "blocking":
            return not self._queue[i]
        return len(self._queue[i]) <= self._next_delay[i]  # async: d actions left, so it arrives just in time

    def act(self, env_ids: Iterable[int]) -> dict[int, np.ndarray]:
        """One action per environment; plans (one batched call) for those that need a new chunk."""
        env_ids = list(env_ids)
        for i in env_ids:  # chunks whose computation has finished reach the agent now
            p = self._pending[i]
            if p is not None and self._step[i] >= p.arrival:
                self._queue[i], self._pending[i] = deque(p.actions), None
                self._received[i].append(p)
        need = [i for i in env_ids if self._wants_plan(i)]
        if need:
            delays = [self._delay_now(i) for i in need]
            for i, d, chunk in zip(need, delays, self._plan(need, delays), strict=True):
                self._receive(i, chunk, d)
        out, planned = {}, []
        for i in env_ids:
            if self._queue[i]:
                self._last[i] = self._queue[i].popleft()
                planned.append(i)
                if self.strategy.kind == "ensemble":
                    self._last[i] = self._ensembled(i)
        if planned and self.strategy.per_step:
            self._correct(planned)
        for i in env_ids:
            if i not in planned:  # an empty queue, waiting for a chunk: Push-T holds its last target, a
                self._last[i] = self.task.waiting_action(self._last[i])  # displacement task stands still
            out[i] = self._last[i]
            self._step[i] += 1
        return out

    def _correct(self, env_ids: list[int]) -> None:
        """The per-step hook on this step's planned actions, one batched call (module docstring)."""
        chunks = [self._received[i][-1] for i in env_ids]  # the executing chunk of each (its actions fill the queue)
        ages = np.array([self._step[i] - c.observed for i, c in zip(env_ids, chunks, strict=True)])
        index = np.array([self.chunk_start + self._step[i] - c.origin for i, c in zip(env_ids, chunks, strict=True)])
        actions = np.stack([self._last[i] for i in env_ids]).astype(np.float32)  # (B, A)
        corrected = self.strategy.correct(self.stacked_obs(env_ids), actions, ages, index)
        if corrected.shape != actions.shape or not np.isfinite(corrected).all():
            raise BCBenchError(f"the correction head returned {corrected.shape} or non-finite actions for "
                               f"{actions.shape}")
        for i, a in zip(env_ids, corrected, strict=True):
            self._last[i] = a

    def _ensembled(self, i: int) -> np.ndarray:
        """ACT's temporal ensemble of every received chunk's action for this step (the queue's chunk among them)."""
        t, cs, tp = self._step[i], self.chunk_start, self.pred_horizon
        self._received[i] = [c for c in self._received[i] if t - c.origin + cs < tp]  # forget finished chunks
        preds = [c.chunk[t - c.origin + cs] for c in self._received[i] if c.arrival <= t and t - c.origin + cs >= 0]
        return ensemble_action(preds, self.strategy.cfg.ensemble_decay)

    def _receive(self, i: int, chunk: np.ndarray, d: int) -> None:
        """Queue a planned chunk now (d = 0) or when its computation ends, as the execution mode says."""
        start, end = self.chunk_start, self.chunk_start + self.action_horizon
        if self.execution == "async":  # the first d actions are in the past when the chunk arrives
            self._next_delay[i] = self._checked_delay(i)
            start, end = start + d, start + d + actions_executed(self.action_horizon, d, self.execution_horizon)
        self.delays.append(d)
        planned = _Chunk(self._origin(i, d), self._step[i] + d, chunk, list(chunk[start:end]), self._step[i])
        if d == 0:
            self._queue[i] = deque(planned.actions)
            self._received[i].append(planned)
        else:
            self._pending[i] = planned
        if self.strategy.kind != "ensemble":
            self._received[i] = self._received[i][-1:]  # only the executing chunk is ever read
