"""The delay model checked in wall-clock time (`bcbench realtime --wall-clock`): the Push-T simulator in real time at
the control rate in this process, the policy in another (`bcbench serve`), both on this machine.

Every other real-time number of bcbench freezes the world at integer steps and hands the controller a delay d. Here
the world never waits: control step k starts at its tick (t0 + k * 0.1 s), executes one action, steps and renders
the simulator, and spends the rest of the period waiting on the socket, so an answer is received (and timed) as it
comes. Execution is the simulated async controller's (bcbench.evaluation.controller), with the delay measured
instead of given:
- a request is sent, from the observation of that step, when the executing chunk has D actions left (the
  controller's threshold, D the delay expected: `plan_delay` where stated, else the median d of the run's calls so
  far, the warm-up calls' before the first: a deployment learns its latency from its own recent calls);
- the answer takes effect at the first control step that starts after it arrived: if that is d steps after the
  request, its first d actions (from chunk_start, the request's step) are in the past and skipped, and the chunk
  runs `actions_executed(action_horizon, D, s)` actions from there; if the queue runs dry first, the agent
  holds its last target (as the controller does);
- d (steps) and the round trip (seconds, this process's monotonic clock), the server's compute time and its own
  time for the request are recorded for every call.
The simulator's own step counts: a step (action, physics, render) that ends after its period is an overrun; the
next step starts at once and the clock is re-anchored there (ROS's Rate does the same), the slip recorded and
reported, never hidden. One episode at a time: real time cannot batch episodes.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from statistics import median
from typing import Any

import numpy as np
import zmq
from tqdm import tqdm

from bcbench.errors import BCBenchError
from bcbench.evaluation.config import WallClockConfig
from bcbench.evaluation.controller import actions_executed, async_actions_needed
from bcbench.evaluation.latency_sources import steps_for
from bcbench.evaluation.wire import WireError, array, decode, encode
from bcbench.tasks.pusht.env import dp_initial_state, make_env
from bcbench.utils.system import CpuContention, provenance


class PolicyClient:
    """A DEALER socket to a policy server: requests go out without waiting; answers are read as they come."""

    def __init__(self, address: str, alive: Any = None) -> None:
        self.address, self.alive = address, alive or (lambda: None)  # alive(): why the server is gone, or None
        self.sock = zmq.Context.instance().socket(zmq.DEALER)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(address)
        self.next_id = 0

    def send(self, kind: str, **fields: Any) -> tuple[int, float]:
        """Send a request; its id and this process's monotonic send time."""
        rid, self.next_id = self.next_id, self.next_id + 1
        t = time.perf_counter()
        self.sock.send_multipart([b"", encode({"type": kind, "id": rid, "sent_at": time.time(), **fields})])
        return rid, t

    def poll(self, timeout_s: float) -> tuple[dict[str, Any], float] | None:
        """The next answer and its arrival time, waiting at most timeout_s (0: only what is there); None if none."""
        if not self.sock.poll(max(0, int(timeout_s * 1e3))):
            return None
        frames = self.sock.recv_multipart()
        return decode(frames[-1]), time.perf_counter()

    def call(self, kind: str, timeout_s: float, **fields: Any) -> tuple[dict[str, Any], float]:
        """A request answered before anything else happens (describe, warm-up): the answer and its round trip (s)."""
        rid, t0 = self.send(kind, **fields)
        deadline = t0 + timeout_s
        while (left := deadline - time.perf_counter()) > 0:
            got = self.poll(min(left, 0.5))
            if got is None:
                if (why := self.alive()) is not None:
                    raise BCBenchError(f"the policy server stopped: {why}")
                continue
            answer, t1 = got
            if answer.get("id") == rid:
                return checked(answer), t1 - t0
        raise BCBenchError(f"the policy server at {self.address} did not answer {kind} in {timeout_s:g} s")

    def close(self) -> None:
        self.sock.close()


def checked(answer: dict[str, Any]) -> dict[str, Any]:
    """An answer, or its error in one line."""
    if answer.get("type") == "error":
        raise BCBenchError(f"the policy server refused a request: {answer.get('error')}")
    return answer


def chunk_of(answer: dict[str, Any], pred_horizon: int) -> np.ndarray:
    """(Tp, 2) float32 actions of a predict answer, checked as the server checks requests (one line if malformed)."""
    try:
        return array(answer.get("actions"), "the server's actions", ("float32", "float64"),
                     (pred_horizon, 2)).astype(np.float32)
    except WireError as exc:
        raise BCBenchError(f"the policy server answered malformed actions: {exc}") from None


@dataclass
class _Episode:
    """One wall-clock episode's state and record."""

    seed: int
    score: float = 0.0
    success: bool = False
    length: int = 0
    final_coverage: float = 0.0
    max_coverage: float = 0.0
    calls: list[dict[str, Any]] = field(default_factory=list)
    overruns: list[dict[str, float]] = field(default_factory=list)
    step_ms: list[float] = field(default_factory=list)  # each step's own work: action, physics, render
    period_ms: list[float] = field(default_factory=list)  # between consecutive step starts
    busy_period_ms: list[float] = field(default_factory=list)  # those while a call was outstanding
    stale_chunks: int = 0  # answers that arrived with every action of theirs in the past
    final_state: list[float] = field(default_factory=list)  # agent x, y, block x, y, angle at the end


def warm_up(client: PolicyClient, meta: dict[str, Any], cfg: WallClockConfig) -> list[float]:
    """Round trips (ms) of cfg.warmup_calls predict calls on a real first observation, before any episode."""
    env = make_env()
    obs, _ = env.reset(options={"reset_to_state": dp_initial_state(cfg.seed_start)})
    window = _window(deque([obs] * meta["obs_horizon"]))
    out = [client.call("predict", cfg.response_timeout_s, obs=window)[1] * 1e3 for _ in range(cfg.warmup_calls)]
    env.close()
    return out


def _window(history: deque) -> dict[str, np.ndarray]:
    return {"image": np.stack([o["pixels"] for o in history]),
            "agent_pos": np.stack([o["agent_pos"] for o in history]).astype(np.float32)}


class Threshold:
    """The re-plan threshold D: fixed where stated, else the median d (rounded up) of the run's last `window` calls,
    `first` (the warm-up calls' d) until one is measured."""

    def __init__(self, fixed: int | None, first: int, window: int = 20) -> None:
        self.fixed, self.first, self.recent = fixed, first, deque(maxlen=window)

    def now(self) -> int:
        if self.fixed:
            return self.fixed
        return max(1, int(np.ceil(np.median(self.recent)))) if self.recent else self.first

    def measured(self, d: int) -> None:
        self.recent.append(d)


def run_episode(client: PolicyClient, meta: dict[str, Any], seed: int, cfg: WallClockConfig, threshold: Threshold
                ) -> _Episode:
    """One episode in real time (the module docstring says how it runs)."""
    cs, tp, dt = meta["chunk_start"], meta["pred_horizon"], cfg.control_dt_s
    env, ep = make_env(), _Episode(seed)
    obs, _ = env.reset(options={"reset_to_state": dp_initial_state(seed)})
    ep.final_coverage = ep.max_coverage = env.coverage()
    history = deque([obs] * meta["obs_horizon"], maxlen=meta["obs_horizon"])
    queue: deque[np.ndarray] = deque()
    last = np.asarray(obs["agent_pos"], dtype=np.float32)  # before any command: stay put (float32, as the controller)
    pending: dict[str, Any] | None = None  # the outstanding call
    answered: tuple[dict[str, Any], float] | None = None  # its answer, once in
    tick = previous_start = time.perf_counter()
    for step in range(cfg.max_steps):
        while answered is None and pending is not None and (left := tick - time.perf_counter()) > 0:
            answered = _take(client.poll(left), pending)  # the idle part of the period, spent listening
        if answered is None and pending is not None:
            answered = _take(client.poll(0), pending)
        if (wait := tick - time.perf_counter()) > 0:
            time.sleep(wait)
        start = time.perf_counter()
        late = start - tick  # > 0: this process woke after the tick (the CPU was busy elsewhere)
        if step:
            ep.period_ms.append((start - previous_start) * 1e3)
            if pending is not None:  # a call was outstanding over this period: the world went on regardless
                ep.busy_period_ms.append(ep.period_ms[-1])
        previous_start = start
        if pending is not None and answered is None and start - pending["t"] > cfg.response_timeout_s:
            why = client.alive()
            raise BCBenchError(f"the policy server did not answer within {cfg.response_timeout_s:g} s"
                               + (f": it stopped ({why})" if why else ""))
        if answered is not None:  # takes effect now: the first step that starts after it arrived
            d = step - pending["step"]
            chunk = chunk_of(answered[0], tp)
            lo, hi = cs + d, min(cs + d + actions_executed(meta["action_horizon"], pending["plan"],
                                                           cfg.execution_horizon), tp)
            queue = deque(chunk[lo:hi])
            ep.stale_chunks += lo >= tp
            ep.calls.append(_call_record(pending, answered, d))
            threshold.measured(d)
            pending = answered = None
        if pending is None and len(queue) <= (plan := threshold.now()):
            rid, t = client.send("predict", obs=_window(history), seed=seed, first=not ep.calls)
            pending = {"id": rid, "t": t, "step": step, "plan": plan}
        if queue:
            last = queue.popleft()
        obs, reward, terminated, _, info = env.step(np.asarray(last, dtype=np.float64))
        ep.length, ep.score = ep.length + 1, max(ep.score, float(reward))
        ep.final_coverage = float(info["coverage"])
        ep.final_state = [*map(float, info["pos_agent"]), *map(float, info["block_pose"])]
        ep.max_coverage, ep.success = max(ep.max_coverage, ep.final_coverage), ep.success or bool(terminated)
        history.append(obs)
        end = time.perf_counter()
        ep.step_ms.append((end - start) * 1e3)
        tick += dt
        if end > tick:  # the step (its late start included) overran its period: the clock slips, recorded
            ep.overruns.append({"step": step, "step_ms": (end - start) * 1e3, "late_start_ms": late * 1e3,
                                "slip_ms": (end - tick) * 1e3})
            tick = end
        if terminated:
            break
    if pending is not None and answered is None:  # the server finishes its call before the next episode starts
        _drain(client, pending, cfg.response_timeout_s)
    env.close()
    return ep


def _take(got: tuple[dict[str, Any], float] | None, pending: dict[str, Any]) -> tuple[dict[str, Any], float] | None:
    """The outstanding call's answer if `got` is it (an answer to an earlier call, e.g. a finished episode's, is
    dropped), else None."""
    if got is None or got[0].get("id") != pending["id"]:
        return None
    checked(got[0])
    return got


def _drain(client: PolicyClient, pending: dict[str, Any], timeout_s: float) -> None:
    """Wait for the outstanding call's answer (dropped: its episode is over), so that the server is idle when the next
    episode starts."""
    deadline = time.perf_counter() + timeout_s
    while (left := deadline - time.perf_counter()) > 0:
        if _take(client.poll(min(left, 0.5)), pending) is not None:
            return
        if (why := client.alive()) is not None:
            raise BCBenchError(f"the policy server stopped: {why}")
    raise BCBenchError(f"the policy server did not answer within {timeout_s:g} s")


def _call_record(pending: dict[str, Any], answered: tuple[dict[str, Any], float], d: int) -> dict[str, Any]:
    answer, arrived = answered
    server_ms = (answer["sent_at"] - answer["received_at"]) * 1e3
    return {"id": pending["id"], "request_step": pending["step"], "plan_delay": pending["plan"], "delay_steps": d,
            "delay_s": arrived - pending["t"], "compute_ms": float(answer["compute_ms"]), "server_ms": server_ms,
            "model_steps": steps_for(arrived - pending["t"])}


def _histogram(values: list[int]) -> dict[str, int]:
    """{"d": count} of whole-step values (delays, re-plan thresholds), as records hold them."""
    v, n = np.unique(np.asarray(values, dtype=int), return_counts=True)
    return {str(int(a)): int(b) for a, b in zip(v, n, strict=True)}


def delay_distribution(steps: list[int], seconds: list[float]) -> dict[str, Any]:
    """Median, p90 and max of the calls' delays, in control steps and in seconds, and the histogram of d."""
    if not steps:
        return {"calls": 0}
    d, sec = np.asarray(steps), np.asarray(seconds)
    return {"calls": len(steps), "median_steps": float(np.median(d)), "p90_steps": float(np.quantile(d, 0.9)),
            "max_steps": int(d.max()), "median_s": float(np.median(sec)), "p90_s": float(np.quantile(sec, 0.9)),
            "max_s": float(sec.max()), "histogram": _histogram(steps)}


def simulated_delay(distribution: dict[str, Any]) -> int:
    """The rule that pairs a wall-clock run with the simulated model: async at d = the calls' median delay in
    steps, rounded up (an even count's median between two d takes the larger)."""
    return max(1, int(np.ceil(distribution["median_steps"])))


def run_wallclock(client: PolicyClient, cfg: WallClockConfig, progress: bool = True) -> dict[str, Any]:
    """Warm up, then cfg.episodes real-time episodes: the run's episodes and summary (the caller adds provenance)."""
    meta, _ = client.call("describe", cfg.response_timeout_s)
    if async_actions_needed(meta["chunk_start"], 1, cfg.execution_horizon) > meta["pred_horizon"]:
        raise BCBenchError(f"execution horizon {cfg.execution_horizon} does not fit a chunk of {meta['pred_horizon']}")
    warm = warm_up(client, meta, cfg)
    threshold = Threshold(cfg.plan_delay, max(1, steps_for(median(warm) / 1e3)))
    episodes = []
    bar = tqdm(range(cfg.episodes), desc=f"wall clock {meta['name']}", unit="episode", disable=not progress)
    with CpuContention() as load:  # the server's own use counts as "other" here: it is another process
        for i in bar:
            episodes.append(run_episode(client, meta, cfg.seed_start + i, cfg, threshold))
            bar.set_postfix(score=f"{np.mean([e.score for e in episodes]):.3f}")
    bar.close()
    calls = [c for e in episodes for c in e.calls]
    dist = delay_distribution([c["delay_steps"] for c in calls], [c["delay_s"] for c in calls])
    step_ms = [m for e in episodes for m in e.step_ms]
    busy = [m for e in episodes for m in e.busy_period_ms]
    summary = {
        "n": len(episodes), "mean_score": float(np.mean([e.score for e in episodes])), "delays": dist,
        "plan_delay": _histogram([c["plan_delay"] for c in calls]),
        "plan_delay_from": "stated" if cfg.plan_delay else "median d of the last 20 calls (the warm-up's first)",
        "warmup_ms": warm, "compute_ms_median": float(np.median([c["compute_ms"] for c in calls])) if calls else None,
        "overruns": sum(len(e.overruns) for e in episodes), "steps": sum(e.length for e in episodes),
        "overruns_by_step_time": sum(o["step_ms"] > cfg.control_dt_s * 1e3 for e in episodes for o in e.overruns),
        "slip_ms": float(sum(o["slip_ms"] for e in episodes for o in e.overruns)),
        "step_ms_median": float(np.median(step_ms)), "step_ms_max": float(np.max(step_ms)),
        "busy_period_ms_median": float(np.median(busy)) if busy else None,
        "busy_period_ms_max": float(np.max(busy)) if busy else None,
        "stale_chunks": sum(e.stale_chunks for e in episodes),
        "simulated_delay": simulated_delay(dist) if calls else None,
    }
    return {"type": "wallclock", "created": datetime.now(UTC).isoformat(timespec="seconds"), "policy": meta["policy"],
            "server": {k: meta[k] for k in ("name", "obs_horizon", "pred_horizon", "action_horizon", "chunk_start",
                                            "server")},
            "wallclock_config": asdict(cfg), "summary": summary, "cpu_contention": load.result,
            "episodes": [{"episode": i, **asdict(e)} for i, e in enumerate(episodes)], **provenance("cpu")}
