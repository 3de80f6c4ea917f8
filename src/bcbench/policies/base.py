"""What the evaluation harness needs of a policy.

A `ChunkPolicy` maps a batch of observation windows in environment units to action chunks in
environment units:

    obs = {"image": uint8 (B, To, 96, 96, 3), "agent_pos": float32 (B, To, 2) in pixels of the 512 world}
    predict_action_chunk(obs) -> float32 (B, pred_horizon, 2), target agent positions in the 512 world

`chunk_start` is the chunk index of the action for the current step (0 when the chunk starts now;
obs_horizon - 1 for policies trained on Diffusion Policy's windows, whose chunk starts at the oldest
observation). History and receding-horizon execution live in `bcbench.evaluation.controller`, never here.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class ChunkPolicy(Protocol):
    name: str
    obs_horizon: int
    pred_horizon: int
    action_horizon: int
    chunk_start: int

    def predict_action_chunk(self, obs: dict[str, np.ndarray]) -> np.ndarray: ...

    def describe(self) -> dict[str, Any]: ...
