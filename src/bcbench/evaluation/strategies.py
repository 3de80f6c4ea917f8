"""Execution strategies: what is done with consecutive action chunks, orthogonal to the execution mode (sync,
blocking, async) and to where the latency comes from. The controller aligns the chunk that is executing to the
new chunk's indices (`target`) and builds the soft mask over the overlap (`prefix_weights`); a `Strategy` makes
the request and times it, so a strategy's own extra compute is part of a measured latency.

- naive: each chunk on its own (bcbench's behaviour before strategies).
- rtc: Real-Time Chunking (Black, Galliker, Levine 2025): the new chunk is sampled inpainted towards the
  executing one, inside the policy's sampler (bcbench.policies.guidance); flow and Diffusion Policy, torch modes.
- bid: Bidirectional Decoding (Liu et al. 2024): N chunks sampled per call (one batched call, the policy's
  `predict_candidates`); the chosen one minimises backward coherence (weighted distance to the executing chunk)
  plus forward contrast (distance to the other strong candidates minus distance to a weaker policy's).
- ensemble: temporal ensembling (ACT, Zhao et al. 2023, Sec. 3.3): each executed action is the average of every
  received chunk's prediction for that step, weights exp(-m i) with i = 0 the oldest; in the controller.
- prefix: training-time Real-Time Chunking (Black, Ren, Equi, Levine 2025, arXiv 2512.05964): a model trained with a
  simulated delay (`delay_train`, bcbench.policies.prefix) is given the actions the delay executes (the frozen part
  of the controller's target from the current step on) as a clean prefix; no guidance, naive's cost.
- correction: A2C2 (Sendai et al. 2025, arXiv 2509.23224): requests are naive; every control step a trained
  correction head (bcbench.policies.correction) adds a residual to the action the executing chunk planned for it,
  from the newest observation and the chunk's age: the controller's per-step hook (`Strategy.correct`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from bcbench.errors import BCBenchError
from bcbench.evaluation.config import StrategyConfig
from bcbench.interface import (
    CandidatePolicy,
    ChunkPolicy,
    CorrectionHead,
    GuidedPolicy,
    Observation,
    PrefixPolicy,
    SelfTimedPolicy,
)
from bcbench.protocol import delay_steps
from bcbench.tasks import task_of

if TYPE_CHECKING:  # the controller itself runs on numpy; generators only pass through to the policy
    import torch

T = TypeVar("T")


def prefix_weights(pred_horizon: int, frozen_end: int, cover_end: int) -> np.ndarray:
    """Real-Time Chunking's soft mask W over the new chunk's indices (its eq. 5, exponential schedule):
    1 for k < frozen_end (actions that execute before the new chunk arrives: the frozen prefix, d of them in the
    paper's indexing), c_k (e^c_k - 1) / (e - 1) with c_k = (cover_end - k) / (cover_end - frozen_end + 1) over the
    rest of the overlap, 0 from cover_end on (where the executing chunk has no action; H - s in the paper)."""
    k = np.arange(pred_horizon, dtype=np.float64)
    cover_end = max(0, min(cover_end, pred_horizon))
    frozen_end = max(0, min(frozen_end, cover_end))
    c = np.clip((cover_end - k) / (cover_end - frozen_end + 1), 0.0, 1.0)
    w = c * np.expm1(c) / (math.e - 1)
    w[k < frozen_end] = 1.0
    w[k >= cover_end] = 0.0
    return w.astype(np.float32)


def _chunk_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean over steps of the Euclidean distance in pixels; broadcasts over leading axes: (..., T, A) -> (...)."""
    return np.linalg.norm(a - b, axis=-1).mean(axis=-1)


def _nearest_mean(dist: np.ndarray, k: int) -> np.ndarray:
    """Each row's mean of its k smallest entries (0 when k = 0)."""
    return np.sort(dist, axis=-1)[:, :k].mean(axis=-1) if k > 0 else np.zeros(dist.shape[0])


def bid_select(candidates: np.ndarray, target: np.ndarray, weights: np.ndarray, modes: int,
               weak: np.ndarray | None = None, start: int = 0) -> np.ndarray:
    """Bidirectional Decoding's choice among one observation's N candidates (N, Tp, A) -> (Tp, A).

    Backward coherence: sum_k W_k |a_k - target_k| / sum_k W_k (no term when W is all zero: the first call of an
    episode); the N / modes most coherent candidates (and as many of the weak policy's) go on. Forward contrast
    over the chunk from `start` (the current step): the mean distance to the nearest half of the other kept
    candidates, minus that to the nearest half of the kept weak samples. The smallest sum wins (the official
    implementation's form). N = 1 returns the one candidate.
    """
    n = candidates.shape[0]
    if n == 1:
        return candidates[0]
    mass = float(weights.sum())

    def backward(chunks: np.ndarray) -> np.ndarray:  # (M, Tp, A) -> (M,): 0 without a previous chunk
        dist = (np.linalg.norm(chunks - target, axis=-1) * weights).sum(-1)
        return dist / mass if mass > 0 else dist

    back = backward(candidates)
    keep = np.argsort(back, kind="stable")[:max(1, n // modes)] if mass > 0 else np.arange(n)
    strong = candidates[keep][:, start:]
    m = len(keep)
    pos = _chunk_distance(strong[:, None], strong[None, :])  # (m, m)
    np.fill_diagonal(pos, np.inf)  # not itself
    score = back[keep] + (_nearest_mean(pos, m // 2) if m > 1 else 0.0)
    if weak is not None:
        kept_weak = weak[np.argsort(backward(weak), kind="stable")[:m]][:, start:]
        score = score - _nearest_mean(_chunk_distance(strong[:, None], kept_weak[None, :]), max(1, m // 2))
    return candidates[keep[int(np.argmin(score))]]


def ensemble_action(predictions: list[np.ndarray], decay: float) -> np.ndarray:
    """ACT's temporal ensemble of one step's predictions, oldest first: sum_i w_i a_i / sum_i w_i, w_i = exp(-m i)."""
    w = np.exp(-decay * np.arange(len(predictions)))
    return (np.tensordot(w, np.stack(predictions), axes=1) / w.sum()).astype(np.float32)


def prefix_mask(weights: np.ndarray, chunk_start: int) -> np.ndarray:
    """The clean prefix of training-time RTC from the controller's soft mask (B, Tp): the frozen actions from the
    current step on (1 exactly on the frozen part: the d actions the delay executes), none before chunk_start (past
    actions never execute, and the model was trained to generate them: bcbench.policies.prefix)."""
    k = np.arange(weights.shape[-1])
    return ((weights == 1.0) & (k >= chunk_start)).astype(np.float32)


class Strategy:
    """Makes each request under a strategy and records its compute time (`last_compute_s`), for measured latency;
    `correct` is the per-step hook (the correction head), timed in `step_compute_s`."""

    def __init__(self, cfg: StrategyConfig, policy: ChunkPolicy, weak: ChunkPolicy | None = None,
                 head: CorrectionHead | None = None) -> None:
        self.cfg, self.kind, self.policy, self.weak, self.head = cfg, cfg.strategy, policy, weak, head
        if self.kind == "rtc":
            if not isinstance(policy, GuidedPolicy):
                raise BCBenchError(f"--strategy rtc: {policy.name} has no guided sampler (flow and Diffusion Policy "
                                   "do, under the torch modes)")
            # the switch is passed only when off, so a guided policy written before it keeps working
            self._jacobian_kw = {} if self.cfg.rtc_jacobian else {"jacobian": False}
            reason = policy.guidance_unavailable(**self._jacobian_kw)
            if reason:
                raise BCBenchError(f"--strategy rtc: {reason}")
        if weak is not None and (self.kind != "bid" or (weak.pred_horizon, weak.chunk_start, task_of(weak).name)
                                 != (policy.pred_horizon, policy.chunk_start, task_of(policy).name)):
            raise BCBenchError("a weak policy goes with --strategy bid and must predict the same chunks as the policy, "
                               "on the same task")
        if self.kind == "prefix":
            if not isinstance(policy, PrefixPolicy):
                raise BCBenchError(f"--strategy prefix: {policy.name} cannot continue a clean prefix (a flow or "
                                   "Diffusion Policy run trained with delay conditioning can)")
            reason = policy.prefix_unavailable()
            if reason:
                raise BCBenchError(f"--strategy prefix: {reason}")
        self._check_head(policy, head)
        self.last_compute_s = self._compute = self._calls_wall = 0.0
        self.step_compute_s: list[float] = []  # every per-step hook call's time (the correction head)

    def _check_head(self, policy: ChunkPolicy, head: CorrectionHead | None) -> None:
        if self.kind == "correction" and head is None:
            raise BCBenchError("--strategy correction needs its trained head: --correction RUN_DIR")
        if head is not None:
            if self.kind != "correction":
                raise BCBenchError("a correction head goes with --strategy correction")
            reason = head.base_mismatch(policy)
            if reason:
                raise BCBenchError(f"--strategy correction: {reason}")

    @property
    def uses_target(self) -> bool:
        """Whether requests need the executing chunk aligned to the new one (RTC, BID, the prefix)."""
        return self.kind in ("rtc", "bid", "prefix")

    @property
    def per_step(self) -> bool:
        """Whether the controller calls `correct` on every step's planned actions (the correction head)."""
        return self.head is not None

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"strategy": self.kind}
        if self.kind == "rtc":
            out["max_guidance"] = self.cfg.rtc_max_guidance
            if not self.cfg.rtc_jacobian:  # absent in records from before the switch: the Jacobian where one exists
                out["jacobian"] = False
        if self.kind == "bid":
            out.update(samples=self.cfg.bid_samples, modes=self.cfg.bid_modes, weak=self.cfg.bid_weak)
        if self.kind == "ensemble":
            out["decay"] = self.cfg.ensemble_decay
        if self.head is not None:
            out["head"] = self.head.describe()
            if self.step_compute_s:  # what the hook cost per step in the episodes (batched over their envs)
                out["per_step_ms"] = {"calls": len(self.step_compute_s),
                                      "median": float(np.median(self.step_compute_s) * 1e3),
                                      "max": float(np.max(self.step_compute_s) * 1e3)}
        return out

    def _timed(self, policy: ChunkPolicy, call: Callable[[], T]) -> T:
        """Run one policy call; add its compute time (the policy's own report when it times itself)."""
        t = time.perf_counter()
        out = call()
        wall = time.perf_counter() - t
        self._compute += policy.last_compute_s if isinstance(policy, SelfTimedPolicy) else wall
        self._calls_wall += wall
        return out

    def _candidates(self, policy: ChunkPolicy, obs: Observation, n: int) -> np.ndarray:
        """(B, n, Tp, A): the policy's own batched sampler, else its observation rows repeated n times."""
        if isinstance(policy, CandidatePolicy):
            return np.asarray(self._timed(policy, lambda: policy.predict_candidates(obs, n)))
        gens = obs.get("generators")
        rep = {"image": np.repeat(obs["image"], n, 0), "agent_pos": np.repeat(obs["agent_pos"], n, 0),
               **({"generators": [g for g in gens for _ in range(n)]} if gens is not None else {})}
        out = np.asarray(self._timed(policy, lambda: policy.predict_action_chunk(rep)))
        return out.reshape(len(obs["agent_pos"]), n, *out.shape[1:])

    def request(self, obs: Observation, target: np.ndarray | None = None, weights: np.ndarray | None = None,
                weak_generators: list[torch.Generator] | None = None) -> np.ndarray:
        """(B, Tp, A) chunks for a batch of observations; target (B, Tp, A) and weights (B, Tp) for rtc and bid."""
        self._compute, self._calls_wall, t0 = 0.0, 0.0, time.perf_counter()
        if self.kind == "rtc":
            chunks = self._timed(self.policy, lambda: self.policy.predict_guided_chunk(
                obs, target, weights, self.cfg.rtc_max_guidance, **self._jacobian_kw))
        elif self.kind == "bid":
            cands = self._candidates(self.policy, obs, self.cfg.bid_samples)
            weak = None
            if self.weak is not None:
                weak = self._candidates(self.weak, {**obs, "generators": weak_generators}, self.cfg.bid_samples)
            start = self.policy.chunk_start
            chunks = np.stack([bid_select(c, target[b], weights[b], self.cfg.bid_modes,
                                          None if weak is None else weak[b], start) for b, c in enumerate(cands)])
        elif self.kind == "prefix":
            mask = prefix_mask(np.asarray(weights), self.policy.chunk_start)
            chunks = self._timed(self.policy, lambda: self.policy.predict_prefixed_chunk(obs, target, mask))
        else:
            chunks = self._timed(self.policy, lambda: self.policy.predict_action_chunk(obs))
        # the strategy's own work (selection) counts too: the wall time outside the policy calls
        self.last_compute_s = self._compute + (time.perf_counter() - t0 - self._calls_wall)
        return np.asarray(chunks)

    def timed_request(self, obs: Observation, target: np.ndarray | None = None, weights: np.ndarray | None = None,
                      weak_generators: list[torch.Generator] | None = None) -> float:
        """What a measured latency times (seconds): the request and, with a per-step hook, the hook's calls while it
        computes. The head runs every control step on the same CPU as the chunk's computation, so a call spanning
        n = ceil(L / 0.1 s) steps (at least 1: the step that asks must act too) is charged n hook calls."""
        chunks = self.request(obs, target, weights, weak_generators)
        total = self.last_compute_s
        if self.head is not None:
            cs = self.policy.chunk_start
            rows = len(chunks)
            self.correct(obs, chunks[:, cs], np.zeros(rows, np.int64), np.full(rows, cs, np.int64))
            step = self.step_compute_s.pop()  # a timing call, not an episode's step
            total += max(1, delay_steps(total)) * step
        self.last_compute_s = total
        return total

    def correct(self, obs: Observation, actions: np.ndarray, ages: np.ndarray, indices: np.ndarray) -> np.ndarray:
        """The per-step hook: (B, A) actions the executing chunks planned for this step, corrected (A2C2); timed."""
        assert self.head is not None
        t = time.perf_counter()
        out = np.asarray(self.head.correct(obs, actions, ages, indices), dtype=np.float32)
        self.step_compute_s.append(self.head.last_compute_s if isinstance(self.head, SelfTimedPolicy)
                                   else time.perf_counter() - t)
        return out
