"""The shared receding-horizon controller: history, batching, which chunk entries run."""

from __future__ import annotations

import numpy as np
import pytest

from bcbench.errors import BCBenchError
from bcbench.evaluation.controller import ChunkedController


class CountingPolicy:
    """Chunk entry k of call c is the action (c, k); records the observation batches it saw."""

    name = "counting"
    obs_horizon, pred_horizon, action_horizon = 2, 16, 8

    def __init__(self, chunk_start: int = 0) -> None:
        self.chunk_start = chunk_start
        self.calls: list[dict[str, np.ndarray]] = []

    def predict_action_chunk(self, obs):
        c = len(self.calls)
        self.calls.append(obs)
        b = obs["agent_pos"].shape[0]
        chunk = np.stack([np.full(16, c), np.arange(16)], axis=-1).astype(np.float32)  # (16, 2)
        return np.repeat(chunk[None], b, axis=0)


def _obs(t: int) -> dict[str, np.ndarray]:
    return {"pixels": np.full((96, 96, 3), t, dtype=np.uint8), "agent_pos": np.array([t, t], dtype=np.float64)}


@pytest.mark.parametrize("chunk_start", [0, 1])
def test_executes_action_horizon_then_replans(chunk_start):
    policy = CountingPolicy(chunk_start)
    ctl = ChunkedController(policy)
    ctl.reset(0, _obs(0))
    actions = []
    for t in range(20):
        actions.append(ctl.act([0])[0])
        ctl.observe(0, _obs(t + 1))
    assert len(policy.calls) == 3  # steps 0, 8, 16
    assert [tuple(a) for a in actions[:9]] == [(0, chunk_start + k) for k in range(8)] + [(1, chunk_start)]
    # At reset the first observation is repeated; at step 8 the history is observations 7 and 8.
    np.testing.assert_array_equal(policy.calls[0]["agent_pos"][0], [[0, 0], [0, 0]])
    np.testing.assert_array_equal(policy.calls[1]["agent_pos"][0], [[7, 7], [8, 8]])
    assert policy.calls[1]["image"].shape == (1, 2, 96, 96, 3)


def test_batches_only_envs_that_need_a_plan():
    policy = CountingPolicy()
    ctl = ChunkedController(policy)
    for e in range(3):
        ctl.reset(e, _obs(0))
    ctl.act([0, 1, 2])
    assert policy.calls[0]["image"].shape[0] == 3
    ctl.drop(1)
    for _ in range(7):
        ctl.act([0, 2])
    ctl.reset(5, _obs(0))  # a newcomer and two due for a re-plan: one call of batch 3
    ctl.act([0, 2, 5])
    assert len(policy.calls) == 2 and policy.calls[1]["image"].shape[0] == 3


def test_rejects_bad_chunks_and_horizons():
    class Bad(CountingPolicy):
        def predict_action_chunk(self, obs):
            return np.zeros((1, 4, 2))

    ctl = ChunkedController(Bad())
    ctl.reset(0, _obs(0))
    with pytest.raises(BCBenchError, match="shape"):
        ctl.act([0])
    with pytest.raises(BCBenchError, match="exceeds"):
        ChunkedController(CountingPolicy(chunk_start=9))
