"""Latency sources for real-time evaluation: how many control steps a policy call takes.

Push-T's control loop runs at 10 Hz (0.1 s per environment step), so a call that takes L seconds takes
d = ceil(L / 0.1) steps (`steps_for`); a task at another rate f (its `control_hz`) takes ceil(L f). L comes from one of:
- a fixed number of milliseconds (`--latency-ms 250`, d = 3);
- `measured`: the policy's own call times on this machine, timed before the episodes with the backend in
  use and through the execution strategy (RTC's backward passes, BID's N samples and selection, the correction
  head's per-step calls while a chunk computes count: Strategy.timed_request), one drawn per call (each episode
  draws from its own stream, seeded by its seed);
- `profile:NAME`: a named hardware profile; `a100` holds the study's A100 inference times.
How the world moves meanwhile (sync, blocking, async) is the controller's business
(`bcbench.evaluation.controller`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bcbench.errors import BCBenchError
from bcbench.evaluation.config import PROFILES as PROFILE_NAMES
from bcbench.evaluation.config import check_latency_options
from bcbench.evaluation.controller import WEAK_STREAM, episode_generator
from bcbench.evaluation.strategies import Strategy, prefix_weights
from bcbench.evaluation.timing import TimingConfig, time_calls
from bcbench.interface import ChunkPolicy, is_generative
from bcbench.protocol import delay_steps
from bcbench.reference import A100_DP_MS, A100_MS
from bcbench.tasks import example_for
from bcbench.utils.system import CpuContention

# Diffusion Policy (and flow matching, the same network) at K steps on the A100: the encoder-and-overhead
# share plus K U-Net calls, from the study's two measured points (K = 10, 100).
_A100_DP_PER_STEP_MS = (A100_DP_MS[100] - A100_DP_MS[10]) / 90
_A100_DP_BASE_MS = A100_DP_MS[10] - 10 * _A100_DP_PER_STEP_MS
PROFILES: dict[str, dict[str, float]] = {"a100": dict(A100_MS)}
assert tuple(PROFILES) == PROFILE_NAMES


def sampler_steps(policy: ChunkPolicy) -> int | None:
    """The step count a generative policy samples with (a hardware profile's time depends on it), else None."""
    return policy.sampler_steps if is_generative(policy) else None


def steps_for(latency_s: float, rate_hz: float | None = None) -> int:
    """Control steps a call of `latency_s` seconds takes: ceil(L / 0.1) (or ceil(L f) at a task's rate f), 0 for no
    latency."""
    if latency_s < 0:
        raise BCBenchError(f"latency must be >= 0, got {latency_s * 1e3:g} ms")
    return delay_steps(latency_s, rate_hz)


def profile_ms(profile: str, policy: str, steps: int | None = None) -> float:
    """A hardware profile's time for one call of `policy` (generative policies: at `steps` steps)."""
    if profile not in PROFILES:
        raise BCBenchError(f"unknown latency profile '{profile}' (known: {', '.join(sorted(PROFILES))})")
    if profile == "a100" and policy in ("diffusion", "flow") and steps:
        return _A100_DP_BASE_MS + steps * _A100_DP_PER_STEP_MS
    if policy not in PROFILES[profile]:
        raise BCBenchError(f"the '{profile}' profile has no inference time for '{policy}'")
    return PROFILES[profile][policy]


def timed_request_inputs(runner: ChunkPolicy, uses_target: bool
                         ) -> tuple[dict[str, Any], np.ndarray | None, np.ndarray | None]:
    """What a timed request is made with: a batch-1 observation and, for a strategy that reads the executing chunk,
    one the policy made (1, Tp, A) followed over half of it, with RTC's soft mask (1, Tp)."""
    obs = example_for(runner)
    if not uses_target:
        return obs, None, None
    target = np.asarray(runner.predict_action_chunk(obs), dtype=np.float32)
    tp, cs = runner.pred_horizon, runner.chunk_start
    return obs, target, prefix_weights(tp, cs + 1, tp - runner.action_horizon)[None]


def interleaved_request_ms(runner: ChunkPolicy, strategies: dict[str, Strategy], rounds: int = 20, calls: int = 5,
                           warmup: int = 10, each_round: Callable[[], None] | None = None
                           ) -> tuple[dict[str, list[list[float]]], dict[str, float] | None]:
    """Each strategy's request times (ms), `rounds` x `calls`, in interleaved rounds after `warmup` untimed calls
    each: strategy -> per-round lists; and what else used the CPUs meanwhile (`CpuContention`, warned about on
    stderr). Timing one strategy after another's hundred episodes made the second 6-9 ms slower for the same
    request (results/strategies-dp-a); interleaving shares whatever the machine drifts. `each_round`, if given,
    runs after every round's requests (other work timed in the same rounds: a per-step hook alone)."""
    obs, target, weights = timed_request_inputs(runner, True)  # strategies that read no target ignore it
    weak_generators = [episode_generator(WEAK_STREAM, 0)]

    def request(s: Strategy) -> float:
        return s.timed_request(obs, target, weights, weak_generators if s.weak is not None else None) * 1e3

    for s in strategies.values():
        for _ in range(warmup):
            request(s)
    out: dict[str, list[list[float]]] = {k: [] for k in strategies}
    with CpuContention() as contention:
        for _ in range(rounds):
            for k, s in strategies.items():
                out[k].append([request(s) for _ in range(calls)])
            if each_round is not None:
                each_round()
    contention.warn(f"the strategies {', '.join(strategies)}")
    return out, contention.result


@dataclass
class LatencySource:
    """Where d comes from: `fixed` (ms), `measured` (call times in ms), or `profile` (a name)."""

    kind: str = "none"
    ms: float = 0.0
    samples_ms: list[float] = field(default_factory=list)
    name: str = ""
    contention: dict[str, float] | None = None
    """measured: what else used the CPUs while the calls were timed (bcbench.utils.system.CpuContention)"""
    rate_hz: float | None = None
    """the task's control rate where it is not the protocol's 10 Hz (Task.delay_rate): what a latency is counted in"""

    @classmethod
    def parse(cls, latency: str | None, latency_ms: float | None) -> LatencySource:
        check_latency_options(latency, latency_ms)
        if latency_ms is not None:
            return cls("fixed", ms=float(latency_ms))
        if latency is None:
            return cls()
        if latency == "measured":
            return cls("measured")
        return cls("profile", name=latency.split(":", 1)[1])

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind}
        if self.kind == "fixed":
            out["ms"] = self.ms
        if self.kind == "profile":
            out.update(name=self.name, ms=self.ms)
        if self.kind == "measured":
            ms = np.array(self.samples_ms)
            out.update(calls=int(ms.size), median_ms=float(np.median(ms)), max_ms=float(ms.max()),
                       cpu_contention=self.contention)
        return out

    def resolve(self, runner: ChunkPolicy, strategy: Strategy) -> None:
        """Fill in what depends on the policy: its profile time, or its measured call times on this machine (a
        request as `strategy` makes it, following a previous chunk where it reads one, so its compute counts)."""
        if self.kind == "profile":
            self.ms = profile_ms(self.name, runner.name, sampler_steps(runner))
        elif self.kind == "measured" and not self.samples_ms:
            obs, target, weights = timed_request_inputs(runner, strategy.uses_target)
            stats = time_calls(lambda: strategy.timed_request(obs, target, weights, None), TimingConfig(),
                               clock=lambda: strategy.last_compute_s, what=f"{runner.name} ({strategy.kind})")
            self.samples_ms, self.contention = stats["samples_ms"], stats["cpu_contention"]

    def delay_fn(self, seeds: dict[int, int]) -> Callable[[int], int]:
        """env id -> d for its next call; measured draws come from each episode's own stream."""
        if self.kind in ("fixed", "profile"):
            d = steps_for(self.ms / 1e3, self.rate_hz)
            return lambda env_id: d
        if self.kind == "measured":
            steps = np.array([steps_for(ms / 1e3, self.rate_hz) for ms in self.samples_ms])
            rngs = {i: np.random.default_rng([7, s]) for i, s in seeds.items()}
            return lambda env_id: int(rngs[env_id].choice(steps))
        return lambda env_id: 0
