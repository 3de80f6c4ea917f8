"""Latency: fast mode returns the reference chunk (same weights, same noise); timing and verdict logic."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from bcbench.bench import _normalizer
from bcbench.fast import make_runner
from bcbench.latency import TimingConfig, latency_record, random_observation, time_calls, verdicts
from bcbench.policies import learned_policies, make_policy
from tests.tiny import tiny_overrides


def _pair(name: str, mode: str):
    torch.manual_seed(0)
    model = make_policy(name, "quick", **tiny_overrides(name)).eval()
    return make_runner("reference", model, _normalizer()), make_runner(mode, model, _normalizer())


def _chunk(runner, obs):
    if hasattr(runner.model, "reset_noise"):
        runner.model.reset_noise(123)  # the same noise for both runners
    return runner.predict_action_chunk(obs)


@pytest.mark.parametrize("mode", ["fast", "fast-jit"])
@pytest.mark.parametrize("name", learned_policies())
def test_fast_equals_reference(name, mode):
    ref, fast = _pair(name, mode)
    obs = random_observation(2)
    a, b = _chunk(ref, obs), _chunk(fast, obs)
    assert a.shape == b.shape == (2, 16, 2)
    # 1e-4 in the normalised action range [-1, 1] = 0.0256 px in the 512 px world
    np.testing.assert_allclose(a / 256.0, b / 256.0, atol=1e-4, rtol=0)


@pytest.mark.parametrize("sampler, steps", [("ddpm", 100), ("ddpm", 10), ("ddim", 10), ("ddim", 3)])
def test_fast_diffusion_matches_every_sampler(sampler, steps):
    ref, fast = _pair("diffusion", "fast")
    ref.model.set_sampler(sampler, steps)
    fast.model.set_sampler(sampler, steps)  # the fast runner works on its own copy of the model
    obs = random_observation(1)
    np.testing.assert_allclose(_chunk(ref, obs) / 256.0, _chunk(fast, obs) / 256.0, atol=1e-4, rtol=0)


def test_fast_modes_do_not_touch_the_callers_model():
    ref, fast = _pair("cnn_mlp", "fast-jit")
    assert isinstance(ref.model.convs, torch.nn.Sequential) and fast.model is not ref.model
    ref, fast = _pair("diffusion", "fast")
    from bcbench.fast import MatmulConv1d

    assert not any(isinstance(m, MatmulConv1d) for m in ref.model.modules())
    assert any(isinstance(m, MatmulConv1d) for m in fast.model.modules())


def test_timing_statistics_and_verdicts():
    few = time_calls(lambda: sum(range(1000)), TimingConfig(warmup=1, min_calls=10, max_calls=10, min_seconds=0.0))
    # fewer than 100 calls: no percentiles, the tail statistic is the maximum and says so
    assert few["calls"] == 10 and few["p99_ms"] is None and few["p90_ms"] is None
    assert few["tail_stat"] == "max of 10" and few["tail_ms"] == few["max_ms"] >= few["median_ms"] >= few["min_ms"]
    many = time_calls(lambda: sum(range(1000)), TimingConfig(warmup=1, min_calls=100, min_seconds=0.0))
    assert many["calls"] == 100 and many["tail_stat"] == "p99" and many["tail_ms"] == many["p99_ms"]
    assert many["min_ms"] <= many["median_ms"] <= many["p90_ms"] <= many["p99_ms"] <= many["max_ms"]
    v = verdicts(120.0, rate_hz=10.0)
    assert v["verdict_statistic"] == "p99"
    assert verdicts(120.0, 10.0, tail_stat="max of 7")["verdict_statistic"] == "max of 7"
    assert v["realtime_chunked"] and not v["realtime_every_step"]
    assert v["max_rate_every_step_hz"] == pytest.approx(1000 / 120)
    assert v["max_rate_chunked_hz"] == pytest.approx(8000 / 120)


def test_latency_record_for_a_trained_style_runner_and_a_baseline():
    ref, _ = _pair("cnn_mlp", "fast")
    timing = TimingConfig(warmup=1, min_calls=3, min_seconds=0.0)
    rec = latency_record(ref, timing)
    assert set(rec["modes"]) == {"reference", "fast"} and rec["hardware"]["torch_threads"] >= 1
    base = latency_record(make_policy("random"), timing)
    assert set(base["modes"]) == {"reference"}
    json.dumps(rec)  # JSON-ready


def test_latency_cli_writes_json_table_and_plot(tmp_path, capsys):
    from bcbench.cli import main

    assert main(["latency", "--policy", "cnn_mlp", "--policy", "random", "--config", "quick", "--quick",
                 "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "latency.json").read_text())
    modes = {(r["policy"], r["mode"]) for r in data["rows"]}
    assert modes == {("cnn_mlp", "reference"), ("cnn_mlp", "fast"), ("random", "reference")}
    assert (tmp_path / "latency.png").stat().st_size > 1000 and "speed-up" in (tmp_path / "latency.md").read_text()


def test_int8_mode_is_close_but_its_own_mode():
    from bcbench.fast import Int8Conv1d

    ref, q = _pair("diffusion", "fast-int8")
    assert any(isinstance(m, Int8Conv1d) for m in q.model.modules())
    obs = random_observation(2)
    a, b = _chunk(ref, obs) / 256.0 - 1, _chunk(q, obs) / 256.0 - 1  # normalised units
    assert np.isfinite(b).all() and np.abs(b).max() <= 1 + 1e-5
    assert np.abs(a - b).max() < 0.5  # approximate, not equal: its deviation is reported, not hidden
    assert q.describe()["mode"] == "fast-int8"
