"""Inference modes: exact forms equal the torch reference; approximate ones are close and say what they are;
exports are cached by checkpoint and rebuilt when it changes; a missing runtime is one clear error."""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile

import numpy as np
import pytest
import torch

from bcbench.cli.main import main
from bcbench.errors import BCBenchError
from bcbench.evaluation.backends import apply_mode, record_graph_inputs, set_mode
from bcbench.modes import EXACT_MODES, MODES, mode_name
from bcbench.policies import learned_policies, make_policy
from tests.tiny import tiny_overrides

TOL = 1e-4  # normalised action units ([-1, 1]): 0.0256 px of the 512 px world


def _model(name: str, **extra):
    torch.manual_seed(0)
    return make_policy(name, "quick", **tiny_overrides(name), **extra).eval()


def _chunks(model, modes, obs, **kw) -> dict[str, np.ndarray]:
    out = {}
    for mode in modes:
        set_mode(model, mode, **kw)
        model.reset_noise(123)  # the same noise in every mode
        with torch.inference_mode():
            out[mode] = model.predict_action_chunk(obs).numpy()
    return out


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    """One float export per policy, reused by every test and sampler (the graphs do not depend on the sampler)."""
    root = tmp_path_factory.mktemp("exports")
    return {name: root / name for name in learned_policies()}


@pytest.mark.parametrize("name", learned_policies())
def test_exact_modes_equal_the_reference(name, exports):
    model = _model(name)
    obs = model.example_obs(2)
    c = _chunks(model, EXACT_MODES, obs, export_dir=exports[name])
    assert c["reference"].shape == (2, 16, 2)
    for mode in EXACT_MODES[1:]:
        np.testing.assert_allclose(c[mode], c["reference"], atol=TOL, rtol=0, err_msg=mode)


@pytest.mark.parametrize("name, sampler, steps", [("diffusion", "ddpm", 100), ("diffusion", "ddim", 10),
                                                  ("diffusion", "ddim", 1), ("flow", "euler", 1),
                                                  ("flow", "euler", 10), ("flow", "midpoint", 2)])
def test_exact_modes_equal_the_reference_for_every_sampler(name, sampler, steps, exports):
    model = _model(name)  # the same seed: the same weights as the export the first test wrote
    model.set_sampler(sampler, steps)
    c = _chunks(model, EXACT_MODES, model.example_obs(1), export_dir=exports[name])
    for mode in EXACT_MODES[1:]:
        np.testing.assert_allclose(c[mode], c["reference"], atol=TOL, rtol=0, err_msg=f"{mode} {sampler}{steps}")


def test_one_step_samplers_make_one_denoiser_call():
    model = _model("flow")
    model.set_sampler("euler", 1)
    calls = record_graph_inputs(model, [model.example_obs(1)])
    assert len(calls["obs_film"]) == 1 and len(calls["denoise"]) == 1
    assert model.deployed is None  # the recorder is removed again


def _int8_constants(export_dir, graph) -> int:
    """How many of an OpenVINO export's constants are stored in 8 bits."""
    import openvino as ov

    ops = ov.Core().read_model(str(export_dir / f"{graph}.xml")).get_ops()
    return sum(o.get_type_name() == "Constant" and o.get_element_type() in (ov.Type.u8, ov.Type.i8) for o in ops)


@pytest.mark.parametrize("name, modes", [("diffusion", ["openvino-bf16"]), ("cnn_mlp", ["openvino-int8"]),
                                         ("flow", ["openvino-int8w"]), ("bct", ["openvino-int8w"]),
                                         ("diffusion", ["onnxruntime-int8"]), ("bct", ["onnxruntime-int8"])])
def test_approximate_modes_are_close_and_labelled(name, modes, exports, tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # where an export without a cache folder goes
    model = _model(name)
    calib = [model.example_obs(1) for _ in range(4)]
    obs = model.example_obs(2)
    int8w = exports[name].with_name(f"{name}-int8w")  # kept (not a temporary export) to read its weights below
    export_dir = int8w if modes[0].endswith("int8w") else None if "int8" in modes[0] else exports[name]
    c = {**_chunks(model, ["fast"], obs), **_chunks(model, modes, obs, calibration=calib, export_dir=export_dir)}
    for mode in modes:
        assert np.isfinite(c[mode]).all()
        assert np.abs(c[mode] - c["fast"]).max() < 0.5, mode  # approximate, not unrelated
    backend, precision = modes[0].split("-")
    assert model.deployment["backend"] == backend and model.deployment["precision"] == precision
    # a temporary export is deleted once compiled (it leaked 15 GB); torch's own compile cache may appear there
    assert not [p for p in tmp_path.iterdir() if not p.name.startswith("torchinductor")]
    if precision == "int8w":
        # weight-only int8: the denoising loop's matrix products get int8 weights (no calibration needed); the
        # encoder, run once per call, stays float; a policy without a loop (BCT) has all its graphs compressed
        for graph in model.graphs:
            assert (_int8_constants(int8w, graph) > 0) == (graph in (model.loop_graphs or model.graphs)), graph
        set_mode(model, "openvino-fp32", export_dir=exports[name])  # the float export (cached if written already)
        assert all(_int8_constants(exports[name], graph) == 0 for graph in model.graphs)
    set_mode(model, "fast")
    assert model.deployed is None and model.deployment == {"backend": "torch", "precision": "fp32"}


def test_mode_names_and_errors(monkeypatch):
    from bcbench.cli.parser import MODES as PARSER_MODES

    assert PARSER_MODES == MODES  # the parser lists them without importing torch
    assert mode_name("torch") == "fast" and mode_name("torch", reference=True) == "reference"
    assert mode_name("openvino", "int8") == "openvino-int8"
    assert mode_name("onnxruntime", "int8") == "onnxruntime-int8"
    assert mode_name("openvino", "int8w") == "openvino-int8w"
    with pytest.raises(BCBenchError, match="unknown backend/precision"):
        mode_name("onnxruntime", "int8w")
    with pytest.raises(BCBenchError, match="needs --backend openvino"):
        mode_name("torch", "bf16")
    with pytest.raises(BCBenchError, match="unknown inference mode"):
        set_mode(_model("cnn_mlp"), "tensorrt")
    monkeypatch.setitem(sys.modules, "openvino", None)  # as if it were not installed
    with pytest.raises(BCBenchError, match="needs the openvino package"):
        set_mode(_model("cnn_mlp"), "openvino-fp32")


def _train_tiny(run, data) -> None:
    sets = [a for k, v in tiny_overrides("cnn_mlp", max_steps=2).items() for a in ("--set", f"{k}={json.dumps(v)}")]
    assert main(["train", "--policy", "cnn_mlp", "--out", str(run), "--data", str(data), "--quiet", *sets]) == 0


def test_export_cache_and_the_eval_cli(synthetic_zarr, tmp_path, monkeypatch, capsys):
    from bcbench.policies.checkpoint import latest_checkpoint, load_runner

    run = tmp_path / "run"
    _train_tiny(run, synthetic_zarr)
    monkeypatch.setenv("BCBENCH_DATA", str(synthetic_zarr))  # int8 calibrates on the run's training split
    # in-process CLI calls: a subprocess per command cost this test about 30 s of start-up
    assert main(["export", str(run), "--precision", "int8"]) == 0
    exports = list((run / "export").iterdir())
    assert [p.name.split("-")[1] for p in exports] == ["int8"] and (exports[0] / "forward.xml").exists()
    assert main(["export", str(run), "--precision", "int8w"]) == 0  # its own cache folder beside int8's
    assert sorted(p.name.split("-")[1] for p in (run / "export").iterdir()) == ["int8", "int8w"]
    shutil.rmtree(next((run / "export").glob("openvino-int8w-*")))

    assert main(["eval", "--checkpoint", str(run), "--backend", "openvino", "--episodes", "2", "--max-steps", "16",
                 "--out", str(tmp_path / "ev"), "--quiet"]) == 0
    result = json.loads((tmp_path / "ev" / "eval.json").read_text())
    assert result["policy"]["mode"] == "openvino-fp32" and result["policy"]["deployment"]["backend"] == "openvino"
    assert sorted(p.name.split("-")[1] for p in (run / "export").iterdir()) == ["float", "int8"]
    assert not list((run / "export").glob("*.tmp"))  # written atomically

    runner = load_runner(run)
    apply_mode(runner, "openvino-bf16")  # the float export serves bf16 too: nothing exported again
    first = runner.model.deployment["export"]
    assert first.split("/")[-1].startswith("openvino-float-")
    stamp = (run / "export" / first.split("/")[-1] / "forward.bin").stat().st_mtime_ns
    apply_mode(runner, "openvino-fp32")
    assert runner.model.deployment["export"] == first
    assert (run / "export" / first.split("/")[-1] / "forward.bin").stat().st_mtime_ns == stamp
    weights = latest_checkpoint(run) / ("ema.safetensors" if runner.info.weights == "ema" else "model.safetensors")
    os.utime(weights, ns=(stamp + 10**9, stamp + 10**9))  # the checkpoint changed: a new export
    runner = load_runner(run)
    apply_mode(runner, "openvino-fp32")
    assert runner.model.deployment["export"] != first

    assert main(["realtime", "--checkpoint", str(run), "--backend", "openvino", "--delays", "1", "--execution",
                 "async", "--measured", "--episodes", "2", "--max-steps", "16", "--out", str(tmp_path / "rt"),
                 "--quiet"]) == 0
    measured = json.loads(next((tmp_path / "rt").glob("*measured*.json")).read_text())
    assert measured["policy"]["mode"] == "openvino-fp32"  # timed and run in the deployed backend

    capsys.readouterr()
    assert main(["eval", "--checkpoint", str(run), "--precision", "bf16"]) == 2
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "--backend openvino" in err


def test_auto_picks_the_faster_of_two_fake_backends():
    """pick_fastest times interleaved rounds and returns the setup whose calls are fastest."""
    import time

    from bcbench.evaluation.auto import pick_fastest

    state = {"delay": 0.0}
    setups = {"slow": lambda: state.update(delay=0.006), "fast": lambda: state.update(delay=0.002)}
    best, medians = pick_fastest(setups, lambda: time.sleep(state["delay"]), rounds=3, calls=2)
    assert best == "fast" and medians["fast"] < medians["slow"] and medians["slow"] >= 6.0


def test_auto_trial_rotates_the_order_and_times_after_the_warm_up():
    """A mode that is slow for its first calls after a switch (cold caches, sleeping threads) but faster after
    them wins, and each round starts at another mode, so none always follows the same one."""
    import time

    from bcbench.evaluation.auto import pick_fastest

    state = {"mode": "", "since_switch": 0}
    firsts: list[str] = []  # the modes in the order the trial switches to them

    def switch(mode: str) -> None:
        firsts.append(mode)
        state.update(mode=mode, since_switch=0)

    def call() -> None:
        cold = state["since_switch"] < 3
        state["since_switch"] += 1
        time.sleep({"warms-up": 0.012 if cold else 0.001, "steady": 0.003}[state["mode"]])

    setups = {m: (lambda m=m: switch(m)) for m in ("warms-up", "steady")}
    best, medians = pick_fastest(setups, call, rounds=2, calls=3, warm=3)
    assert best == "warms-up" and medians["warms-up"] < 2.5 <= medians["steady"]
    assert firsts == ["warms-up", "steady", "steady", "warms-up"]  # round 2 starts at the second mode
    firsts.clear()
    assert pick_fastest(setups, call, rounds=2, calls=3, warm=1)[0] == "steady"  # the trial as it was


def test_backend_auto_chooses_an_exact_mode_records_why_and_caches(synthetic_zarr, tmp_path):
    from bcbench.evaluation.auto import CANDIDATES
    from bcbench.policies.checkpoint import load_runner
    from bcbench.training.loop import TrainOptions, new_run, train

    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False)
    run = new_run("cnn_mlp", "quick", tiny_overrides("cnn_mlp", max_steps=2), tmp_path / "r", opts)
    train(run, opts)
    runner = load_runner(run)
    apply_mode(runner, mode_name("auto"))
    trial = runner.info.deployment["auto"]
    assert runner.info.mode == trial["chosen"] in CANDIDATES and set(trial["median_ms"]) == set(CANDIDATES)
    assert "interleaved" in trial["why"] and trial["cpu_flags"] is not None and trial["cached"] is False
    again = load_runner(run)
    apply_mode(again, "auto")
    assert again.info.deployment["auto"]["cached"] is True and again.info.mode == trial["chosen"]
    with pytest.raises(BCBenchError, match="auto picks among the exact"):
        mode_name("auto", "int8")


def test_on_a_gpu_auto_is_torch_and_an_exported_cpu_runtime_is_refused(synthetic_zarr, tmp_path):
    """Seen on a lent H200: `eval --device cuda --latency measured` defaulted to auto, which tried OpenVINO."""
    from bcbench.policies.checkpoint import load_runner
    from bcbench.training.loop import TrainOptions, new_run, train

    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False)
    run = new_run("cnn_mlp", "quick", tiny_overrides("cnn_mlp", max_steps=1), tmp_path / "r", opts)
    train(run, opts)
    runner = load_runner(run)
    runner.device = torch.device("cuda")  # what apply_mode reads; nothing here runs on it
    apply_mode(runner, "auto")
    assert runner.info.mode == "fast" and "only torch" in runner.info.deployment["auto"]["why"]
    assert not (run / "export").exists()  # nothing exported, nothing timed
    for mode in ("openvino-fp32", "onnxruntime-fp32"):
        with pytest.raises(BCBenchError, match=r"runs on the CPU.*--backend torch or auto"):
            apply_mode(runner, mode)


@pytest.mark.parametrize("argv,want", [
    (["realtime", "--checkpoint", "r", "--measured"], "auto"),  # the measured latency sets the delays
    (["realtime", "--checkpoint", "r"], "torch"),
    (["eval", "--checkpoint", "r", "--latency", "measured", "--execution", "async"], "auto"),
    (["eval", "--checkpoint", "r"], "torch"),  # scores only: the reference runtime
    (["eval", "--checkpoint", "r", "--latency", "measured", "--backend", "openvino"], "openvino"),
    (["realtime", "--checkpoint", "r", "--measured", "--reference"], "torch"),
])
def test_the_default_backend_is_auto_where_measured_latency_sets_the_delays(argv, want):
    from bcbench.cli.parser import build_parser
    from bcbench.cli.policies import backend

    assert backend(build_parser().parse_args(argv)) == want


def test_tiers_compare_modes_paired_on_the_seeds_asked(synthetic_zarr, tmp_path, monkeypatch, capsys):
    """`bcbench tiers`: an exact mode deviates by rounding only, int8 is labelled and paired; --seed-start picks
    validation seeds for a run that is not a final preset, and the table says which."""
    run = tmp_path / "run"
    _train_tiny(run, synthetic_zarr)
    monkeypatch.setenv("BCBENCH_DATA", str(synthetic_zarr))  # observations from the run's validation split
    assert main(["tiers", str(run), "--mode", "onnxruntime-fp32", "--mode", "onnxruntime-int8", "--episodes", "2",
                 "--seed-start", "200000", "--observations", "4", "--out", str(tmp_path / "t"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "score over 2 validation seeds from 200000" in out
    record = json.loads((tmp_path / "t" / "tiers.json").read_text())
    rows = {r["mode"]: r for r in record["rows"]}
    assert record["seed_start"] == 200_000 and set(rows) == {"fast", "onnxruntime-fp32", "onnxruntime-int8"}
    assert rows["onnxruntime-fp32"]["max_deviation_px"] < 0.05  # exact: float rounding only
    assert rows["onnxruntime-int8"]["paired_vs_fast"]["n"] == 2
    seeds = [e["seed"] for e in json.loads((tmp_path / "t" / "eval-fast" / "eval.json").read_text())["episodes"]]
    assert seeds == [200_000, 200_001]


@pytest.mark.parametrize("name", ["cnn_mlp", "diffusion"])
def test_a_deployed_policy_runs_its_torch_glue_on_one_thread_and_gives_the_threads_back(name):
    """With a runtime running the graphs, torch's intra-op workers would spin on the cores the runtime uses:
    every entry point of the runner computes its glue on one torch thread, and the torch modes keep theirs."""
    from bcbench.evaluation.benchmark import _normalizer
    from bcbench.interface import example_observation
    from bcbench.policies.learned import PolicyRunner

    model = _model(name)
    set_mode(model, "fast")  # the graphs' torch form, which the stand-in runtime below calls
    runner = PolicyRunner(model, _normalizer())
    obs = example_observation(2, runner.obs_horizon)
    seen: list[int] = []

    def graph(method):
        def call(*args):
            seen.append(torch.get_num_threads())
            return getattr(model, method)(*args)
        return call

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        model.reset_noise(0)
        torch_mode = runner.predict_action_chunk(obs)
        model.deployed = {g: graph(g) for g in model.graphs}  # a stand-in runtime: the torch methods, counted
        model.reset_noise(0)
        deployed = runner.predict_action_chunk(obs)
        assert seen and set(seen) == {1} and torch.get_num_threads() == 2
        # the same chunk, up to the stand-in network's own sums on one thread (TOL: normalised units, 256 px each)
        np.testing.assert_allclose(deployed, torch_mode, atol=TOL * 256)
        seen.clear()
        runner.predict_candidates(obs, 2)
        if runner.model.guidable:
            runner.predict_guided_chunk(obs, torch_mode, np.ones(torch_mode.shape[:2]), 5.0, jacobian=False)
        assert seen and set(seen) == {1} and torch.get_num_threads() == 2
        model.deployed = None
        model.call_graph = lambda g, *a: seen.append(torch.get_num_threads()) or getattr(model, g)(*a)
        seen.clear()
        runner.predict_action_chunk(obs)
        assert set(seen) == {2}  # torch modes run their networks with every thread
    finally:
        torch.set_num_threads(before)


def test_fc_kernel_benchmark_moves_fully_connected_layers_off_mlas_with_the_same_outputs():
    """benchmarks/fc_kernel.py's no-op clamp changes OpenVINO's kernel for every fully connected layer (its
    comparison means nothing otherwise) and not the arithmetic."""
    pytest.importorskip("openvino")
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(__file__)), "benchmarks"))
    try:
        from fc_kernel import chain_model, clamp_fully_connected, compile_openvino, fc_profile
    finally:
        sys.path.pop(0)

    model, weights = chain_model(4, 64, 32, 3, np.random.default_rng(0))
    x = np.random.default_rng(1).standard_normal((4, 64), dtype=np.float32)
    plain = compile_openvino(model, 1)
    assert clamp_fully_connected(model) == 3
    moved = compile_openvino(model, 1)
    want = np.concatenate([x @ w.T for w in weights], 1)
    for request in (plain, moved):
        np.testing.assert_allclose(request.infer([x])[0], want, atol=1e-5)
    assert fc_profile(moved)["layers"] == 3
    assert not any("mlas" in e for e in fc_profile(moved)["exec_types"])
