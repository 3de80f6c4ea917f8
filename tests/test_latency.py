"""Latency: timing statistics, verdicts, records of every mode, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.benchmark import _normalizer
from bcbench.evaluation.timing import TimingConfig, latency_record, time_calls, verdicts
from bcbench.policies import make_policy
from bcbench.policies.learned import PolicyRunner
from tests.tiny import tiny_overrides


def _runner(name: str) -> PolicyRunner:
    torch.manual_seed(0)
    return PolicyRunner(make_policy(name, "quick", **tiny_overrides(name)), _normalizer())


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
    # the re-plan interval its chunked verdict used is recorded (a figure's budget line reads it): 3 at 80 Hz
    m = verdicts(30.0, 80.0, action_horizon=3)
    assert m["action_horizon"] == 3 and m["realtime_chunked"] and not m["realtime_every_step"]


def test_latency_record_for_a_trained_style_runner_and_a_baseline():
    runner = _runner("diffusion")
    apply_mode(runner, "reference")
    timing = TimingConfig(warmup=1, min_calls=3, min_seconds=0.0)
    rec = latency_record(runner, timing, modes=("reference", "fast", "openvino-fp32"))
    assert set(rec["modes"]) == {"reference", "fast", "openvino-fp32"} and rec["hardware"]["torch_threads"] >= 1
    assert rec["modes"]["openvino-fp32"]["deployment"]["backend"] == "openvino"
    assert runner.info.mode == "reference" and runner.model.deployed is None  # put back as it was
    base = latency_record(make_policy("random"), timing)
    assert set(base["modes"]) == {"reference"}
    json.dumps(rec)  # JSON-ready


def test_latency_cli_writes_json_table_and_plot(tmp_path, capsys):
    from bcbench.cli.main import main

    assert main(["latency", "--policy", "cnn_mlp", "--policy", "random", "--config", "quick", "--quick",
                 "--mode", "reference", "--mode", "openvino-bf16", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "latency.json").read_text())
    modes = {(r["policy"], r["mode"]) for r in data["rows"]}
    assert modes == {("cnn_mlp", "reference"), ("cnn_mlp", "openvino-bf16"), ("random", "reference")}
    assert (tmp_path / "latency.png").stat().st_size > 1000 and "speed-up" in (tmp_path / "latency.md").read_text()


def test_latency_includes_auto_by_default(monkeypatch, tmp_path):
    """Without --mode, every mode and `auto` (what a user gets: the fastest exact mode here) are timed."""
    import bcbench.evaluation.benchmark as benchmark
    from bcbench.modes import AUTO, MODES

    seen = []
    monkeypatch.setattr(benchmark, "_rows_for", lambda name, preset, modes, *a, **k: seen.append(modes) or [])
    benchmark.run_latency_benchmark(policies=["cnn_mlp"], presets=["quick"], out=str(tmp_path))
    assert seen == [[*MODES, AUTO]]


def test_every_row_is_set_against_the_best_limits_the_run_measured():
    """A slow moment while the limits were measured must not flatter a row: the floor uses the run's best."""
    from bcbench.evaluation.floor import against_floor

    work = {"weight_bytes": 1e9, "flops": 1e9, "median_ms": 100.0}
    rows = [{**work, "machine_limits": {"read_gb_per_s": 10.0, "gemm_gflop_per_s": 50.0, "threads": 2}},
            {**work, "machine_limits": {"read_gb_per_s": 20.0, "gemm_gflop_per_s": 20.0, "threads": 2}},
            {"median_ms": 1.0}]  # a baseline: no limits, no floor
    best = against_floor(rows)
    assert best["read_gb_per_s"] == 20.0 and best["gemm_gflop_per_s"] == 50.0
    assert all(r["floor_ms"] == pytest.approx(50.0) and r["bound"] == "memory" for r in rows[:2])  # 1 GB / 20 GB/s
    assert rows[0]["x_floor"] == pytest.approx(2.0) and "x_floor" not in rows[2]
    assert against_floor([{"median_ms": 1.0}]) is None


def test_the_floor_counts_weights_per_use_and_flops():
    """A loop of K denoising steps reads the U-Net K times: 10 steps read more than 1, and the floor is the larger
    of the memory and compute times."""
    from bcbench.evaluation.benchmark import _normalizer
    from bcbench.evaluation.floor import call_work, floor_ms
    from bcbench.policies import make_policy
    from bcbench.policies.learned import PolicyRunner
    from tests.tiny import TINY

    model = make_policy("diffusion", "quick", **TINY["diffusion"])
    runner = PolicyRunner(model, _normalizer())
    model.set_sampler("ddim", 1)
    one = call_work(runner)
    model.set_sampler("ddim", 10)
    ten = call_work(runner)
    assert ten["weight_bytes"] > one["weight_bytes"] > 0 and ten["flops"] > one["flops"] > 0
    f = floor_ms(ten, {"read_gb_per_s": 10.0, "gemm_gflop_per_s": 1e6})
    assert f["bound"] == "memory" and f["floor_ms"] == pytest.approx(ten["weight_bytes"] / 1e10 * 1e3)


@pytest.mark.parametrize("name", ["cnn_mlp", "bct", "diffusion"])
def test_the_per_layer_floor_splits_the_call_and_is_never_below_the_whole_call_floor(name):
    """layer_work's per-module bytes and FLOPs add up to call_work's, and the per-layer roofline (no overlap between
    layers) lies between the whole-call floor (perfect overlap) and the sum of the memory and compute times."""
    from bcbench.evaluation.benchmark import _normalizer
    from bcbench.evaluation.floor import call_work, floor_ms, layer_floor_ms, layer_work
    from bcbench.policies import make_policy
    from bcbench.policies.learned import PolicyRunner
    from tests.tiny import TINY

    model = make_policy(name, "quick", **TINY[name]).eval()
    runner = PolicyRunner(model, _normalizer())
    if model.samplers:
        model.set_sampler(model.samplers[0], 3)
    whole = call_work(runner)  # the first call fills caches (DP's step embeddings); both count the steady state
    layers, whole = layer_work(runner), call_work(runner)
    assert len(layers) > 3 and len({x["module"] for x in layers}) == len(layers)
    assert sum(x["weight_bytes"] for x in layers) == whole["weight_bytes"]
    assert sum(x["flops"] for x in layers) == pytest.approx(whole["flops"])
    from torch.utils.flop_counter import FlopCounterMode  # an independent count: the split loses no FLOP

    from bcbench.interface import example_observation

    # with a hook on every module, as layer_work has: hooks turn off torch's fused transformer fast path, whose
    # attention products the FLOP counter would not see
    hooks = [m.register_forward_pre_hook(lambda *_: None) for m in model.modules()]
    deployed, model.deployed = model.deployed, None
    with FlopCounterMode(display=False) as independent:
        model.reset_noise(0)
        runner.predict_action_chunk(example_observation(1, runner.obs_horizon))
    model.deployed = deployed
    for h in hooks:
        h.remove()
    assert whole["flops"] == pytest.approx(independent.get_total_flops()) and whole["flops"] > 0
    limits = {"read_gb_per_s": 10.0, "gemm_gflop_per_s": 50.0}
    f = floor_ms(whole, limits)
    assert f["floor_ms"] <= layer_floor_ms(layers, limits) <= f["memory_ms"] + f["compute_ms"] + 1e-9


def test_a_timing_records_and_warns_when_another_process_used_the_cpus(capsys):
    """The brief's rule (never report a timing taken while something else ran) becomes checkable: every timing
    records the CPUs other processes used meanwhile, and says so on stderr when they did."""
    import subprocess
    import sys
    import time

    from bcbench.utils.system import machine_cpu_seconds

    if machine_cpu_seconds() is None:
        pytest.skip("no /proc/stat on this system")
    spin = subprocess.Popen([sys.executable, "-c", "import time\nt = time.time()\nwhile time.time() - t < 5: pass"])
    try:
        time.sleep(0.3)  # the spinner is running
        stats = time_calls(lambda: time.sleep(0.01), TimingConfig(warmup=0, min_calls=100, min_seconds=1.5,
                                                                max_calls=1000), what="a sleeping call")
    finally:
        spin.kill()
        spin.wait()
    busy = stats["cpu_contention"]
    assert busy["other_cpus"] > 0.5 and busy["seconds"] >= 1.5  # one spinning core, whatever else ran
    assert "while timing a sleeping call, other processes used" in capsys.readouterr().err



def test_a_timings_own_cpu_use_is_not_counted_as_other(monkeypatch):
    """A machine where only this process runs (its busy time is this process's CPU time): nothing "other"."""
    import time

    from bcbench.utils import system

    monkeypatch.setattr(system, "machine_cpu_seconds", lambda: (system.own_cpu_seconds() + 100.0, 7.0))
    with system.CpuContention() as own:
        t = time.perf_counter()
        while time.perf_counter() - t < 0.3:
            pass
    assert own.result is not None and own.result["other_cpus"] < 0.02 and own.result["steal_cpus"] == 0.0


CPUINFO = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 17
model name\t: AMD EPYC
stepping\t: 1
flags\t\t: fpu avx2 avx512f

processor\t: 1
vendor_id\t: GenuineIntel
cpu family\t: 6
model\t\t: 207
model name\t: other
stepping\t: 2
"""


def test_a_record_names_the_cpu_by_family_and_model_not_only_by_its_generic_name():
    from bcbench.analysis.results import cpu_text
    from bcbench.utils.system import _cpuinfo_first, cpu_id_of, hardware

    fields = _cpuinfo_first(CPUINFO)  # the first processor's block only
    assert fields["model name"] == "AMD EPYC" and cpu_id_of(fields) == "AuthenticAMD family 25 model 17 stepping 1"
    assert cpu_id_of({"model name": "Neoverse", "CPU part": "0xd0c"}) is None  # ARM's cpuinfo has no family
    hw = {"cpu_model": "AMD EPYC", "cpu_id": cpu_id_of(fields), "cpu_flags": ["avx2", "avx512f"]}
    assert cpu_text(hw) == "AMD EPYC [AuthenticAMD family 25 model 17 stepping 1] (avx2, avx512f)"
    assert cpu_text({"cpu_model": "AMD EPYC", "cpu_flags": ["avx2"]}) == "AMD EPYC (avx2)"  # older records as before
    rec = hardware()
    assert "cpu_id" in rec
    if Path("/proc/cpuinfo").exists() and "vendor_id" in Path("/proc/cpuinfo").read_text():
        assert rec["cpu_id"] and " family " in rec["cpu_id"]
