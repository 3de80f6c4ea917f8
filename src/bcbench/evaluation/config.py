"""What an evaluation is asked to do (torch-free: the command line reads its defaults and help from here)."""

from __future__ import annotations

from dataclasses import dataclass, field

from bcbench.errors import BCBenchError
from bcbench.protocol import CONTROL_DT_S, TEST_SEED_START
from bcbench.tasks import DEFAULT_TASK, get_task

EXECUTIONS = ("sync", "blocking", "async")  # how the world moves while the policy computes (see the controller)
# what is done with chunks across re-plans (see the controller and bcbench.evaluation.strategies)
STRATEGIES = ("naive", "rtc", "bid", "ensemble", "prefix", "correction")
PROFILES = ("a100",)  # hardware latency profiles (bcbench.evaluation.latency_sources holds their times)


def torch_only(strategies: list[str] | tuple[str, ...], rtc_jacobian: bool = True) -> str:
    """Why these strategies must run in a torch mode (one line), or "": Real-Time Chunking's guidance on flow takes
    a vector-Jacobian product through the network, which an exported graph does not compute (apply_mode applies it
    to policies whose guidance needs autograd only: Diffusion Policy's needs none; nor does --rtc-no-jacobian)."""
    return "rtc's guidance needs autograd: torch only" if "rtc" in strategies and rtc_jacobian else ""


def check_latency_options(latency: str | None, latency_ms: float | None) -> None:
    """One line for a bad --latency / --latency-ms pair (what LatencySource.parse accepts)."""
    if latency_ms is not None and latency is not None:
        raise BCBenchError("give --latency-ms or --latency, not both")
    if latency_ms is not None and latency_ms < 0:
        raise BCBenchError(f"--latency-ms must be >= 0, got {latency_ms:g}")
    if latency is None or latency == "measured":
        return
    if not latency.startswith("profile:"):
        raise BCBenchError(f"--latency must be 'measured' or 'profile:NAME', got '{latency}'")
    if latency.split(":", 1)[1] not in PROFILES:
        raise BCBenchError(f"unknown latency profile '{latency.split(':', 1)[1]}' (known: {', '.join(PROFILES)})")


@dataclass
class StrategyConfig:
    """How consecutive chunks are joined (bcbench.evaluation.strategies), orthogonal to the execution mode."""

    strategy: str = "naive"
    """naive (each chunk on its own), rtc (Real-Time Chunking: guided inpainting of the new chunk towards the one
    executing; flow under torch, Diffusion Policy under every backend), bid (Bidirectional Decoding: the best of
    N sampled chunks), ensemble (ACT's temporal ensembling of every chunk's action for the step), prefix
    (training-time RTC: a model trained with delay conditioning continues the actions the delay executes) or
    correction (A2C2: a trained correction head adds a residual to every step's action)"""
    rtc_max_guidance: float = 5.0
    """RTC: the guidance weight's clip beta (Black et al. 2025, Sec. 4.2; their default 5; 0 = no guidance)"""
    rtc_jacobian: bool = True
    """RTC: guide through the network's Jacobian (a backward pass), as the paper does, where the policy's guidance has
    one (flow; Diffusion Policy always takes J = I); off: J = I for flow too, the clean estimate moved directly (no
    backward pass, naive's cost, every backend; an extension, not the paper's method)"""
    bid_samples: int = 16
    """BID: chunks sampled per call, N (Liu et al. 2024)"""
    bid_modes: int = 3
    """BID: the backward criterion keeps the N / modes most coherent chunks for the forward one (their K = 3)"""
    bid_weak: str | None = None
    """BID: a weaker checkpoint (e.g. an early one of the same run) for the forward contrast's negatives; none:
    forward term of the positives only"""
    ensemble_decay: float = 0.01
    """ensemble: w_i = exp(-m i) over the chunks predicting a step, i = 0 the oldest (ACT's m, Zhao et al. 2023)"""
    correction: str | None = None
    """correction: the correction head's run (`bcbench train --policy correction --set base=RUN_DIR`), trained on
    the policy being run as its frozen base"""

    def variant_extra(self) -> dict[str, bool]:
        """What a sweep's record adds to its variant beyond the strategy's name: RTC's form when not the paper's."""
        return {"rtc_jacobian": False} if self.strategy == "rtc" and not self.rtc_jacobian else {}

    def __post_init__(self) -> None:
        if self.strategy not in STRATEGIES:
            raise BCBenchError(f"--strategy must be one of {', '.join(STRATEGIES)}, got '{self.strategy}'")
        if self.rtc_max_guidance < 0 or self.ensemble_decay < 0:
            raise BCBenchError("--rtc-max-guidance and --ensemble-decay must be >= 0")
        if self.bid_samples < 1 or self.bid_modes < 1:
            raise BCBenchError(f"--bid-samples and --bid-modes must be >= 1, got {self.bid_samples}, {self.bid_modes}")
        if self.bid_weak is not None and self.strategy != "bid":
            raise BCBenchError("--bid-weak goes with --strategy bid")
        if (self.correction is None) != (self.strategy != "correction"):
            raise BCBenchError("--strategy correction needs its head, --correction RUN_DIR, and --correction goes with "
                               "--strategy correction only")


@dataclass
class EvalConfig:
    episodes: int = 40
    """evaluation episodes (the study used 40)"""
    seed_start: int = TEST_SEED_START
    """episode i uses seed seed_start + i"""
    max_steps: int | None = None
    """steps per episode at most (default: the task's cap, Push-T's 300)"""
    task: str = DEFAULT_TASK
    """the task the episodes run (`pusht`, `metaworld/NAME`); a trained policy's must match it"""
    action_horizon: int | None = None
    """actions executed per chunk (default: the policy's own, 8)"""
    workers: int | None = None
    """simulator processes (default: one per core)"""
    video: int = 0
    """write videos of the first N episodes"""
    video_size: int = 256
    """video frame size in pixels"""
    execution: str = "sync"
    """sync (the world waits for the policy), blocking or async (it does not): see bcbench.evaluation.controller"""
    latency: str | None = None
    """where a call's latency comes from: 'measured' or 'profile:NAME' (or latency_ms)"""
    latency_ms: float | None = None
    """a fixed latency per call in milliseconds"""
    execution_horizon: int | None = None
    """async: actions of each chunk executed before the next one replaces it (s; Real-Time Chunking's execution
    horizon, Diffusion Policy's latency experiment uses 8); default: the action horizon minus the delay"""
    strategy: StrategyConfig = field(default_factory=StrategyConfig)
    """how consecutive chunks are joined (naive, rtc, bid, ensemble) and the strategy's parameters"""

    def __post_init__(self) -> None:
        if self.episodes < 1:
            raise BCBenchError(f"--episodes must be >= 1, got {self.episodes}")
        task = get_task(self.task)  # also checks the task's name
        if self.max_steps is None:
            self.max_steps = task.max_steps
        limit = task.step_limit or 10_000
        if not 1 <= self.max_steps <= limit:
            raise BCBenchError(f"--max-steps must be in 1..{limit}" + (f" ({task.name}'s simulator allows no more)"
                                                                         if task.step_limit else "")
                               + f", got {self.max_steps}")
        if self.seed_start < 0:
            raise BCBenchError(f"--seed-start must be >= 0, got {self.seed_start}")
        if self.workers is not None and self.workers < 1:
            raise BCBenchError(f"--workers must be >= 1, got {self.workers}")
        if self.video < 0 or self.video > self.episodes:
            raise BCBenchError(f"--video must be in 0..episodes ({self.episodes}), got {self.video}")
        if self.action_horizon is not None and self.action_horizon < 1:
            raise BCBenchError(f"--action-horizon must be >= 1, got {self.action_horizon}")

        if self.execution not in EXECUTIONS:
            raise BCBenchError(f"--execution must be one of {', '.join(EXECUTIONS)}, got '{self.execution}'")
        if self.execution_horizon is not None and (self.execution_horizon < 1 or self.execution != "async"):
            raise BCBenchError("--execution-horizon goes with --execution async and must be >= 1, got "
                               f"{self.execution_horizon} with {self.execution}")
        check_latency_options(self.latency, self.latency_ms)
        if isinstance(self.strategy, dict):  # from a result file or a study spec
            self.strategy = StrategyConfig(**self.strategy)


@dataclass
class WallClockConfig:
    """What a wall-clock run is asked to do."""

    episodes: int = 100
    """episodes, one at a time (real time cannot batch them)"""
    seed_start: int = TEST_SEED_START
    """episode i uses seed seed_start + i, as `bcbench eval`"""
    max_steps: int = 300
    """control steps per episode at most"""
    execution_horizon: int | None = None
    """actions of each chunk executed before the next is asked for (s); default: the action horizon minus the
    threshold"""
    plan_delay: int | None = None
    """control steps a call is expected to take: the re-plan threshold (default: the median d of the run's last 20
    calls, the warm-up calls' before the first)"""
    warmup_calls: int = 10
    """predict calls before the first episode (they warm the server up and measure the expected delay)"""
    response_timeout_s: float = 60.0
    """a call not answered in this long stops the run (the server is gone or stuck)"""
    control_dt_s: float = CONTROL_DT_S
    """the control period (Push-T's 10 Hz)"""

    def __post_init__(self) -> None:
        if self.episodes < 1 or not 1 <= self.max_steps <= 10_000 or self.seed_start < 0:
            raise BCBenchError("--episodes must be >= 1, --max-steps in 1..10000 and --seed-start >= 0")
        if self.execution_horizon is not None and self.execution_horizon < 1:
            raise BCBenchError(f"--execution-horizon must be >= 1, got {self.execution_horizon}")
        if self.plan_delay is not None and self.plan_delay < 1:
            raise BCBenchError(f"--plan-delay must be >= 1 (an answer takes effect at the next step at the earliest), "
                               f"got {self.plan_delay}")
        if self.warmup_calls < 1 or self.response_timeout_s <= 0 or self.control_dt_s <= 0:
            raise BCBenchError("warm-up calls must be >= 1, the response timeout and the control period > 0")
