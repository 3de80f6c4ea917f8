"""The nested tables of a study spec's [study] table (`realtime`, `resources`), validated; `bcbench.study.spec`
reads the rest."""

from __future__ import annotations

from typing import Any

from bcbench.errors import BCBenchError
from bcbench.evaluation.config import STRATEGIES
from bcbench.evaluation.latency_sources import PROFILES

REALTIME_KEYS = {"delays", "execution", "profiles", "measured", "strategies", "execution_horizon", "rtc_jacobian"}


def realtime_table(rt: Any) -> dict[str, Any]:
    """[study] realtime = { delays = [1, 2, 4, 8], execution = ["blocking", "async"], profiles = ["a100"],
    measured = true }, validated; defaults fill what is left out."""
    if not isinstance(rt, dict) or set(rt) - REALTIME_KEYS:
        raise BCBenchError(f"study.realtime must be a table with keys {', '.join(sorted(REALTIME_KEYS))}")
    out = {"delays": rt.get("delays", [1, 2, 4, 8]), "executions": rt.get("execution", ["blocking", "async"]),
           "profiles": rt.get("profiles", []), "measured": rt.get("measured", True),
           "strategies": rt.get("strategies", ["naive"]), "execution_horizon": rt.get("execution_horizon"),
           "rtc_jacobian": rt.get("rtc_jacobian", True)}  # RTC's form (StrategyConfig.rtc_jacobian)
    if not out["strategies"] or any(k not in STRATEGIES for k in out["strategies"]):
        raise BCBenchError(f"study.realtime.strategies must list some of {', '.join(STRATEGIES)}")
    s = out["execution_horizon"]
    if s is not None and (not isinstance(s, int) or isinstance(s, bool) or s < 1):
        raise BCBenchError("study.realtime.execution_horizon must be a whole number of actions >= 1")
    if not all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in out["delays"]):
        raise BCBenchError("study.realtime.delays must be whole numbers of control steps >= 0")
    if not set(out["executions"]) <= {"blocking", "async"} or not out["executions"]:
        raise BCBenchError("study.realtime.execution must list blocking and/or async")

    if not isinstance(out["rtc_jacobian"], bool):
        raise BCBenchError("study.realtime.rtc_jacobian must be true (the paper's RTC) or false (J = I)")
    if any(p not in PROFILES for p in out["profiles"]) or not isinstance(out["measured"], bool):
        raise BCBenchError(f"study.realtime.profiles must be among {', '.join(PROFILES)}; measured true or false")
    return out


def resources_table(table: Any) -> dict[str, dict[str, float]]:
    """[study] resources = { train = { cpus = 1 }, eval = { cpus = 1, gpus = 0 } }: what each kind of stage asks
    of Ray (`bcbench study --ray`), validated."""
    kinds = ("train", "eval", "latency", "realtime")
    if not isinstance(table, dict) or set(table) - set(kinds):
        raise BCBenchError(f"study.resources must be a table with keys among {', '.join(kinds)}, got {table!r}")
    for kind, res in table.items():
        ok = isinstance(res, dict) and not set(res) - {"cpus", "gpus"} and all(
            isinstance(v, int | float) and not isinstance(v, bool) and v >= 0 for v in res.values())
        if not ok or res.get("cpus", 1) <= 0:
            raise BCBenchError(f"study.resources.{kind} must be {{ cpus = N > 0, gpus = N >= 0 }}, got {res!r}")
    return {k: dict(v) for k, v in table.items()}
