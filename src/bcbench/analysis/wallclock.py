"""Reading a wall-clock run (`bcbench realtime --wall-clock`) against the simulated delay model: both scores, paired
on episode seeds, with a 95% paired-bootstrap interval. Reads result files only (no torch).

The rule: the simulated twin is async execution at the fixed d = the wall-clock calls' median delay in control
steps, rounded up (`summary.simulated_delay` of the record), on the same episode seeds, step cap and execution
horizon, the policy in the same inference mode. Where the two should agree: every call of the wall-clock run
took that d, its re-plan threshold was d (each call's `plan_delay`), no step overran its period; then the agent
executes the same actions from the same observations as the model's. Where they need not: calls of
another d (jitter: a call near a multiple of 0.1 s lands on either side, and the 2 cores are shared by the
simulator, the policy server and anything else running), overruns (the simulator's own step time slips the clock),
a threshold other than d, and the observation itself: the wall-clock request carries the observation of the step it
is sent at, exactly as the model does, so a difference is not the observation's age but which d each call got.
"""

from __future__ import annotations

from typing import Any

from bcbench.errors import BCBenchError
from bcbench.protocol import delay_steps
from bcbench.stats import paired_bootstrap
from bcbench.utils.io import read_json


def scores(record: dict[str, Any]) -> dict[int, float]:
    return {int(e["seed"]): float(e["score"]) for e in record["episodes"]}


def simulated_d(record: dict[str, Any]) -> int | None:
    """The fixed delay (steps) of an async evaluation record at --latency-ms, else None."""
    cfg = record.get("eval_config") or {}
    if cfg.get("execution") != "async" or cfg.get("latency_ms") is None:
        return None
    return delay_steps(cfg["latency_ms"] / 1e3)


def check_pair(wallclock: dict[str, Any], simulated: dict[str, Any]) -> None:
    """One line if `simulated` is not the wall-clock run's twin by the rule (module docstring)."""
    if wallclock.get("type") != "wallclock":
        raise BCBenchError("the first record is not a wall-clock run (bcbench realtime --wall-clock)")
    want, got = wallclock["summary"].get("simulated_delay"), simulated_d(simulated)
    if want is None:
        raise BCBenchError("the wall-clock run recorded no policy call: nothing to pair")
    if got != want:
        what = "not async at a fixed --latency-ms" if got is None else f"at d = {got}"
        raise BCBenchError(f"the simulated record is {what}; the wall-clock run pairs with async at d = {want} "
                           "(its calls' median delay)")
    w, s = wallclock["wallclock_config"], simulated["eval_config"]
    for key in ("execution_horizon", "max_steps"):
        if w.get(key) != s.get(key):
            raise BCBenchError(f"the two runs differ in {key} ({w.get(key)} against {s.get(key)})")
    a, b = (r.get("policy") or {} for r in (wallclock, simulated))
    for key in ("weights_sha256", "sampler", "steps", "mode"):
        if a.get(key) != b.get(key):
            raise BCBenchError(f"the two runs ran different policies: {key} {a.get(key)} against {b.get(key)}")


def wallclock_comparison(wallclock: dict[str, Any], simulated: dict[str, Any], seed: int = 0) -> dict[str, Any]:
    """Wall-clock score, simulated-delay score, and their paired difference (wall clock minus model)."""
    check_pair(wallclock, simulated)
    wall, model = scores(wallclock), scores(simulated)
    shared = sorted(set(wall) & set(model))
    if not shared:
        raise BCBenchError("the two runs share no episode seed")
    diff, lo, hi, n = paired_bootstrap(wall, [model], seed=seed)
    s, dist = wallclock["summary"], wallclock["summary"]["delays"]
    d = s["simulated_delay"]
    at_d = dist["histogram"].get(str(d), 0) / dist["calls"]
    plans = s["plan_delay"]  # histogram of the calls' thresholds
    return {"d": d, "n": n, "wallclock": sum(wall[k] for k in shared) / n,
            "simulated": sum(model[k] for k in shared) / n,
            "diff": diff, "ci": [lo, hi], "share_at_d": at_d,
            "plan_at_d": plans.get(str(d), 0) / max(1, sum(plans.values())),
            "overruns": s["overruns"], "steps": s["steps"], "delays": dist,
            "rule": "simulated async at d = the wall-clock calls' median delay in control steps (rounded up), "
                    "paired on episode seeds"}


def comparison_lines(c: dict[str, Any]) -> list[str]:
    """The comparison in a few printed lines, with what makes the two differ in this run."""
    dist = c["delays"]
    lines = [f"wall clock {c['wallclock']:.3f}   simulated async d = {c['d']} {c['simulated']:.3f}   "
             f"difference {c['diff']:+.3f} [{c['ci'][0]:+.3f}, {c['ci'][1]:+.3f}] (95% paired bootstrap, "
             f"{c['n']} episode seeds)",
             f"  delays measured: median {dist['median_steps']:g} steps ({dist['median_s'] * 1e3:.0f} ms), p90 "
             f"{dist['p90_steps']:g}, max {dist['max_steps']} over {dist['calls']} calls; {100 * c['share_at_d']:.0f}% "
             f"of them at d = {c['d']} (histogram {dist['histogram']})"]
    apart = []
    if c["share_at_d"] < 1:
        apart.append(f"{100 * (1 - c['share_at_d']):.0f}% of the calls took another d than the model's")
    if c["plan_at_d"] < 1:
        apart.append(f"{100 * (1 - c['plan_at_d']):.0f}% of the requests went out at a threshold other than the "
                     f"model's {c['d']} actions left")
    if c["overruns"]:
        apart.append(f"{c['overruns']} of {c['steps']} steps overran the control period")
    lines.append("  where they can differ here: " + ("; ".join(apart) if apart else
                                                      "nothing measured (every call at d, no overrun): "
                                                      "a difference is noise"))
    return lines


def compare_files(wallclock_path: str, simulated_path: str) -> dict[str, Any]:
    """wallclock_comparison of two result files."""
    return wallclock_comparison(read_json(wallclock_path), read_json(simulated_path))
