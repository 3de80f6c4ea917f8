"""Outside policies for the tests of `--policy module:factory`: one that keeps the contract, and one per way to
break it."""

from __future__ import annotations

import time
from typing import Any

import numpy as np


class Toward:
    """Keeps bcbench's interface: every target is a fixed point (a policy from outside the package)."""

    name = "toward"
    obs_horizon, pred_horizon, action_horizon, chunk_start = 2, 16, 8, 0

    def __init__(self, x: float = 256.0, y: float = 256.0, shape: tuple[int, ...] | None = None,
                 dtype: str = "float32", value: float | None = None, fail: bool = False) -> None:
        self.target, self.shape, self.dtype, self.value, self.fail = (x, y), shape, dtype, value, fail

    def predict_action_chunk(self, obs: dict[str, Any]) -> np.ndarray:
        if self.fail:
            raise RuntimeError("the model file is missing")
        b = len(obs["agent_pos"])
        out = np.empty(self.shape or (b, self.pred_horizon, 2), self.dtype)
        out[...] = self.target if self.value is None else self.value
        return out

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "target": list(self.target), "parameters": 0}


def good(x: float = 256.0, y: float = 256.0) -> Toward:
    return Toward(x, y)


class _NoDescribe:
    name, obs_horizon, pred_horizon, action_horizon, chunk_start = "nodescribe", 2, 16, 8, 0

    def predict_action_chunk(self, obs: dict[str, Any]) -> np.ndarray:
        return np.zeros((len(obs["agent_pos"]), 16, 2), np.float32)


def missing() -> _NoDescribe:
    return _NoDescribe()


def wrong_shape() -> Toward:
    return Toward(shape=(2, 8, 2))


def wrong_dtype() -> Toward:
    return Toward(dtype="int64")


def nan() -> Toward:
    return Toward(value=float("nan"))


def raises() -> Toward:
    return Toward(fail=True)


def factory_raises() -> Toward:
    raise ValueError("no such checkpoint")


class Sleepy(Toward):
    """A policy whose every call takes a known time (it sleeps `ms`), for the wall-clock tests: at 10 Hz, 250 ms is
    d = 3 control steps."""

    name = "sleepy"

    def __init__(self, ms: float = 250.0) -> None:
        super().__init__()
        self.ms = float(ms)

    def predict_action_chunk(self, obs: dict[str, Any]) -> np.ndarray:
        time.sleep(self.ms / 1e3)
        return super().predict_action_chunk(obs)

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "name": self.name, "sleep_ms": self.ms}


def sleepy(ms: float = 250.0) -> Sleepy:
    return Sleepy(ms)
