"""The evaluation harness end to end on the baselines, with a couple of short episodes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bcbench.env.pusht import dp_initial_state
from bcbench.errors import BCBenchError
from bcbench.evaluate import EvalConfig, evaluate
from bcbench.policies import REGISTRY, is_learned, make_policy
from bcbench.stats import bootstrap_ci, score_summary


def test_harness_on_a_baseline_with_two_episodes(tmp_path):
    cfg = EvalConfig(episodes=2, max_steps=24, workers=2, video=1)
    result = evaluate(make_policy("random"), cfg, tmp_path, progress=False)
    on_disk = json.loads((tmp_path / "eval.json").read_text())
    assert on_disk["summary"]["n"] == 2
    for key in ("policy", "eval_config", "summary", "episodes", "git_commit", "hardware", "versions"):
        assert key in on_disk
    assert on_disk["hardware"]["torch_threads"] >= 1 and on_disk["hardware"]["cpu_model"]
    eps = result["episodes"]
    assert [e["seed"] for e in eps] == [100000, 100001]
    np.testing.assert_allclose(eps[1]["initial_state"], dp_initial_state(100001))
    for e in eps:
        assert 0.0 <= e["score"] <= 1.0 and 1 <= e["length"] <= 24
    assert eps[0]["video"] and (tmp_path / "videos").is_dir() and eps[1]["video"] is None
    s = result["summary"]
    assert s["env_steps"] == sum(e["length"] for e in eps)
    assert s["policy_calls"] == 3  # 24 steps / 8 actions per chunk, both episodes in one batch


def test_evaluation_is_deterministic():
    cfg = EvalConfig(episodes=2, max_steps=16, workers=1)
    a = evaluate(make_policy("scripted"), cfg, None, progress=False)
    b = evaluate(make_policy("scripted"), cfg, None, progress=False)
    assert [e["score"] for e in a["episodes"]] == [e["score"] for e in b["episodes"]]


@pytest.mark.parametrize("name", sorted(n for n in REGISTRY if not is_learned(n)))
def test_baselines_return_chunks(name):
    policy = make_policy(name)
    obs = {"image": np.zeros((3, 2, 96, 96, 3), np.uint8), "agent_pos": np.full((3, 2, 2), 200, np.float32)}
    chunk = policy.predict_action_chunk(obs)
    assert chunk.shape == (3, policy.pred_horizon, 2)
    assert np.isfinite(chunk).all() and chunk.min() >= 0 and chunk.max() <= 512


def test_bad_eval_config_and_unknown_policy():
    with pytest.raises(BCBenchError):
        EvalConfig(episodes=0)
    with pytest.raises(BCBenchError):
        EvalConfig(episodes=2, video=3)
    with pytest.raises(BCBenchError, match="unknown policy"):
        make_policy("nope")
    with pytest.raises(BCBenchError, match="unknown config"):
        make_policy("random", "huge")


def test_bootstrap_intervals():
    lo, hi = bootstrap_ci(np.array([0.0, 1.0] * 20))
    assert lo < 0.5 < hi and lo > 0.3 and hi < 0.7
    assert bootstrap_ci(np.zeros(40)) == (0.0, 0.0)
    s = score_summary(np.array([0.2, 0.6, 0.95, 1.0]), np.array([0, 0, 0, 1]), np.array([0.1, 0.5, 0.9, 0.96]))
    assert s["share_above_0.5"]["value"] == 0.75 and s["share_above_0.9"]["value"] == 0.5
    assert s["success_rate"]["value"] == 0.25
