"""The trainer: exact resume after SIGKILL, NaN stop, checkpoint round trip, budget, CLI smoke."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import pytest
import torch

from bcbench.errors import BCBenchError
from bcbench.policies import learned_policies
from bcbench.policies.checkpoint import latest_checkpoint, load_runner
from bcbench.training.loop import TrainOptions, new_run, prepare, train
from bcbench.utils.io import read_jsonl
from tests.tiny import checkpoint_weights, tiny_overrides

EXE = os.path.join(os.path.dirname(sys.executable), "bcbench")


@pytest.fixture
def one_thread():
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


def _opts(data) -> TrainOptions:
    return TrainOptions(data=str(data), threads=1, progress=False)


KILL_AT_STEP = """
import os, signal, sys
from bcbench.training.loop import TrainOptions, train
kill = lambda r: os.kill(os.getpid(), signal.SIGKILL) if r.state.step == 7 else None
train(sys.argv[1], TrainOptions(data=sys.argv[2], threads=1, progress=False, callbacks=(kill,)))
"""


def test_sigkill_then_resume_gives_identical_weights(synthetic_zarr, tmp_path, one_thread):
    """fp32: a run killed with SIGKILL after step 7 and resumed from step 6 ends bit-identical."""
    overrides = tiny_overrides("cnn_mlp", epochs=6, checkpoint_every=3, precision="fp32")
    full = new_run("cnn_mlp", "quick", overrides, tmp_path / "full", _opts(synthetic_zarr))
    summary = train(full, _opts(synthetic_zarr))
    assert summary["stopped"] == "finished" and summary["step"] >= 9 and summary["precision"] == "fp32"

    killed = new_run("cnn_mlp", "quick", overrides, tmp_path / "killed", _opts(synthetic_zarr))
    proc = subprocess.run([sys.executable, "-c", KILL_AT_STEP, str(killed), str(synthetic_zarr)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == -9, proc.stderr  # died by SIGKILL, after the checkpoint of step 6
    assert json.loads((killed / "checkpoints" / "latest.json").read_text())["step"] == 6
    resumed = train(killed, _opts(synthetic_zarr))
    assert resumed["step"] == summary["step"] and resumed["samples"] == summary["samples"]
    a, b = checkpoint_weights(full), checkpoint_weights(killed)
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k
    steps = [m["step"] for m in map(json.loads, (killed / "metrics.jsonl").read_text().splitlines())
             if "train_loss" in m]
    assert steps == sorted(set(steps))  # no step logged twice after the resume


def test_nan_loss_stops_with_clear_error_and_keeps_checkpoint(synthetic_zarr, tmp_path, monkeypatch, one_thread):
    from bcbench.policies.cnn_mlp import CNNMLPPolicy

    run = new_run("cnn_mlp", "quick", tiny_overrides("cnn_mlp", epochs=5), tmp_path / "nan", _opts(synthetic_zarr))
    real = CNNMLPPolicy.compute_loss
    calls = {"n": 0}

    def poisoned(self, batch):
        if self.training:
            calls["n"] += 1
            if calls["n"] == 3:
                return real(self, batch) * float("nan")
        return real(self, batch)

    monkeypatch.setattr(CNNMLPPolicy, "compute_loss", poisoned)
    with pytest.raises(BCBenchError, match=r"loss is nan at step 3.*last good checkpoint"):
        train(run, _opts(synthetic_zarr))
    ckpt = latest_checkpoint(run)
    assert ckpt is not None and ckpt.name == "step_0000002"
    assert load_runner(run).model.num_parameters() > 0  # the last good checkpoint loads


@pytest.mark.parametrize("name", learned_policies())
def test_checkpoint_roundtrip_every_policy(name, synthetic_zarr, tmp_path, one_thread):
    run = new_run(name, "quick", tiny_overrides(name, max_steps=2, ema=True), tmp_path / name, _opts(synthetic_zarr))
    states = {}
    opts = dataclasses.replace(_opts(synthetic_zarr), callbacks=(lambda r: states.update(model=r.model, ema=r.ema),))
    train(run, opts)
    runner = load_runner(run, use_ema=False)
    for k, v in states["model"].state_dict().items():
        assert torch.equal(v, runner.model.state_dict()[k]), k
    ema_runner = load_runner(run, use_ema=True)
    assert ema_runner.describe()["weights"] == "ema"
    ema_state = states["ema"].model.state_dict()
    for k, v in ema_runner.model.state_dict().items():
        assert torch.equal(v, ema_state[k]), k


def test_safety_stop_marks_the_schedule_unfinished(synthetic_zarr, tmp_path, one_thread):
    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False, max_minutes=1e-6)
    run = new_run("cnn_mlp", "quick", tiny_overrides("cnn_mlp", epochs=50), tmp_path / "budget", opts)
    s = train(run, opts)
    assert s["stopped"] == "stopped by time: schedule not finished" and s["step"] == 1
    assert latest_checkpoint(run).name == "step_0000001"


def test_step_budget_sizes_the_schedule(synthetic_zarr, tmp_path, one_thread):
    """A step budget ends the run on time with its cosine schedule annealed to zero."""
    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False)
    run = new_run("bct", "quick", tiny_overrides("bct", epochs=50, max_steps=6, warmup_steps=2), tmp_path / "s", opts)
    s = train(run, opts)
    assert s["stopped"] == "finished" and s["step"] == s["total_steps"] == 6
    lrs = [m["lr"] for m in read_jsonl(run / "metrics.jsonl") if "lr" in m]
    assert lrs[-1] == pytest.approx(0.0, abs=1e-12) and max(lrs) == pytest.approx(1e-3)


def test_runs_written_before_step_budgets_still_load(synthetic_zarr, tmp_path):
    from bcbench.policies.config import OptimConfig, config_from_dict

    assert config_from_dict(OptimConfig, {"epochs": 3, "max_minutes": 14}).epochs == 3  # retired field dropped


def test_existing_run_and_bad_override_are_errors(synthetic_zarr, tmp_path):
    opts = _opts(synthetic_zarr)
    new_run("cnn_mlp", "quick", {}, tmp_path / "r", opts)
    with pytest.raises(BCBenchError, match="already holds a run"):
        new_run("cnn_mlp", "quick", {}, tmp_path / "r", opts)
    with pytest.raises(BCBenchError, match="unknown config field"):
        new_run("cnn_mlp", "quick", {"optim.nope": 1}, tmp_path / "s", opts)
    with pytest.raises(BCBenchError, match="nothing to train"):
        new_run("random", "quick", {}, tmp_path / "t", opts)


def test_cli_train_then_eval_smoke(synthetic_zarr, tmp_path):
    """End to end as a user runs it: train a tiny policy for a few steps, then evaluate the checkpoint."""
    run = tmp_path / "run"
    sets = [a for k, v in tiny_overrides("cnn_mlp", max_steps=3).items() for a in ("--set", f"{k}={json.dumps(v)}")]
    proc = subprocess.run([EXE, "train", "--policy", "cnn_mlp", "--out", str(run), "--data", str(synthetic_zarr),
                           "--quiet", *sets], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "stopped (finished) at step 3/3" in proc.stdout
    proc = subprocess.run([EXE, "eval", "--checkpoint", str(run), "--episodes", "2", "--max-steps", "16",
                           "--out", str(tmp_path / "ev"), "--quiet"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    result = json.loads((tmp_path / "ev" / "eval.json").read_text())
    assert result["policy"]["name"] == "cnn_mlp" and result["summary"]["n"] == 2
    assert result["policy"]["checkpoint"] == "step_0000003"


def test_precise_batchnorm_sets_exact_population_statistics():
    from bcbench.training.loop import precise_batchnorm

    class Net(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.bn = torch.nn.BatchNorm1d(3)

        def compute_loss(self, batch):
            return self.bn(batch["x"]).sum()

    torch.manual_seed(0)
    batches = [{"x": torch.randn(16, 3) * 2 + 5} for _ in range(7)]
    net = Net()
    for b in batches:  # ordinary training leaves momentum estimates
        net.train().compute_loss(b)
    precise_batchnorm(net, batches)
    allx = torch.cat([b["x"] for b in batches])
    torch.testing.assert_close(net.bn.running_mean, allx.mean(0), rtol=1e-5, atol=1e-5)
    # cumulative average of per-batch unbiased variances
    var = torch.stack([b["x"].var(0, unbiased=True) for b in batches]).mean(0)
    torch.testing.assert_close(net.bn.running_var, var, rtol=1e-5, atol=1e-5)
    assert net.bn.momentum == 0.1 and net.training  # momentum and mode restored


def test_bf16_autocast_trains_and_is_recorded(synthetic_zarr, tmp_path, one_thread):
    from bcbench.utils.system import cpu_has_bf16

    run = new_run("diffusion", "quick", tiny_overrides("diffusion", max_steps=3, precision="bf16"), tmp_path / "b",
                  _opts(synthetic_zarr))
    s = train(run, _opts(synthetic_zarr))
    assert s["precision"] == "bf16" and s["step"] == 3 and s["val_loss"] == s["val_loss"]  # finite, not NaN
    auto = prepare(new_run("cnn_mlp", "quick", tiny_overrides("cnn_mlp"), tmp_path / "a", _opts(synthetic_zarr)),
                   _opts(synthetic_zarr))
    assert auto.precision == ("bf16" if cpu_has_bf16() else "fp32")


def test_precision_is_fixed_at_the_first_segment_and_every_segment_names_its_cpu(synthetic_zarr, tmp_path,
                                                                               one_thread, monkeypatch):
    """`auto` resolves once: a run resumed on a CPU that would resolve differently keeps its precision and its
    segments.jsonl says the new machine computes it natively or not (no silent change of numerics)."""
    import bcbench.training.loop as train_mod
    from bcbench.utils.system import cpu_flags

    run = new_run("cnn_mlp", "quick", tiny_overrides("cnn_mlp", max_steps=2, epochs=10), tmp_path / "p",
                  _opts(synthetic_zarr))
    monkeypatch.setattr(train_mod, "resolve_precision", lambda requested, device: "bf16")
    train(run, _opts(synthetic_zarr))  # first segment: auto -> bf16 (as on an AVX512-BF16 CPU)
    meta = json.loads((run / "run.json").read_text())
    meta["config"]["optim"]["max_steps"] = 4  # a longer budget, so that a second segment trains
    (run / "run.json").write_text(json.dumps(meta))
    monkeypatch.setattr(train_mod, "resolve_precision", lambda requested, device: "fp32")  # an AVX2-only CPU
    monkeypatch.setattr(train_mod, "cpu_has_bf16", lambda: False)
    s = train(run, _opts(synthetic_zarr))
    seg = read_jsonl(run / "segments.jsonl")
    assert [x["start_step"] for x in seg] == [0, 2] and s["precision"] == "bf16"
    assert [x["precision"] for x in seg] == ["bf16", "bf16"] and seg[1]["precision_native"] is False
    assert "emulated" in seg[1]["note"] and seg[1]["cpu_flags"] == list(cpu_flags()) and s["segments"] == seg
    assert "this CPU" in seg[1]["note"] and [x["gpu"] for x in seg] == [None, None]  # a GPU is named where used


def test_a_run_records_its_presets_values_and_deviations(synthetic_zarr, tmp_path):
    """What the report (which reads files only) needs of the preset is in run.json."""
    run = new_run("diffusion", "cpu", {"optim.batch_size": 256, "optim.lr": 1e-3}, tmp_path / "r",
                  _opts(synthetic_zarr))
    meta = json.loads((run / "run.json").read_text())
    assert meta["preset_values"] == {"optim.batch_size": 64, "optim.lr": 5e-4}
    assert "U-Net" in meta["preset_deviations"]


def test_periodic_rollouts_log_a_learning_curve(synthetic_zarr, tmp_path, one_thread):
    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False, eval_every=2, eval_episodes=2)
    run = new_run("cnn_mlp", "quick", tiny_overrides("cnn_mlp", max_steps=4, epochs=10), tmp_path / "lc", opts)
    train(run, opts)
    evals = [m for m in read_jsonl(run / "metrics.jsonl") if "eval_score" in m]
    assert [m["step"] for m in evals] == [2, 4] and all(m["eval_seed_start"] == 200_000 for m in evals)
    assert all(m["samples"] == m["step"] * 4 and m["wall_time_s"] > 0 for m in evals)


def test_old_trainer_worker_times_steps_and_refuses_what_it_cannot_build(synthetic_zarr):
    """benchmarks/old_trainer_step.py (train_throughput --old-commit) answers 'ready', then one step time per
    requested step; a policy its code lacks gets one error line instead of a crash."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root / "src"), "BCBENCH_DATA": str(synthetic_zarr)}
    worker = [sys.executable, str(root / "benchmarks" / "old_trainer_step.py")]
    net = {k: v for k, v in tiny_overrides("cnn_mlp").items() if not k.startswith("optim.batch")}
    proc = subprocess.run([*worker, "cnn_mlp", json.dumps(net), "4", "1"], input="2\n1\n", capture_output=True,
                          text=True, env=env, timeout=300)
    lines = [json.loads(x) for x in proc.stdout.splitlines()]
    assert proc.returncode == 0 and "ready" in lines[0], proc.stderr
    assert [len(x) for x in lines[1:]] == [2, 1] and all(t > 0 for x in lines[1:] for t in x)
    proc = subprocess.run([*worker, "no_such_policy", "{}", "4", "1"], input="1\n", capture_output=True, text=True,
                          env=env, timeout=300)
    assert proc.returncode == 0 and "unknown policy" in json.loads(proc.stdout.splitlines()[0])["error"]


def test_train_profile_sums_op_time_into_families():
    """benchmarks/train_profile.py: aten ops land in their family, unknown ones in 'other', and a profiled
    step's convolution shows up as convolution forward and backward."""
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    try:
        import train_profile as tp
    finally:
        sys.path.pop(0)
    assert tp.family("aten::convolution_backward") == "convolution backward"
    assert tp.family("aten::native_group_norm_backward").startswith("normalisation")
    assert tp.family("aten::_fused_adamw_") == "optimiser and EMA" and tp.family("aten::no_such_op") == "other"
    conv = torch.nn.Conv2d(3, 4, 3)
    x = torch.rand(2, 3, 8, 8)

    def step() -> None:
        conv(x).relu().sum().backward()

    fams, top, wall = tp.profile_steps(step, 2)
    assert fams["convolution backward"] > 0 and fams["convolution forward"] > 0 and wall > 0
    assert len(top) <= 12 and all(ms >= 0 for ms in top.values())


def test_keep_freed_memory_reuses_big_blocks_instead_of_faulting_them_in():
    """With it, a freed 64 MB block is reused by the next allocation; without, glibc unmaps it and the next one
    page-faults all over again (a training step's activations are such blocks)."""
    code = ("import resource, sys, torch\n"
            "from bcbench.training.parts import keep_freed_memory\n"
            "assert sys.argv[1] == '0' or keep_freed_memory()\n"
            "torch.ones(16 << 20).sum()\n"
            "before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
            "for _ in range(10):\n"
            "    torch.ones(16 << 20).sum()\n"
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)\n")
    faults = {k: int(subprocess.run([sys.executable, "-c", code, k], capture_output=True, text=True,
                                    check=True).stdout) for k in "01"}
    assert faults["1"] * 4 < faults["0"], faults


class _Boom:
    """What a malicious state.pt could hold: unpickling it would call os.system."""

    def __reduce__(self):
        return (os.system, ("echo pwned > /tmp/bcbench-pwned",))


def test_a_crafted_pickle_in_a_checkpoint_is_refused_with_one_line(synthetic_zarr, tmp_path, one_thread, capsys):
    from bcbench.cli.main import main

    run = new_run("cnn_mlp", "quick", tiny_overrides("cnn_mlp", max_steps=2, epochs=10), tmp_path / "p",
                  _opts(synthetic_zarr))
    train(run, _opts(synthetic_zarr))
    torch.save({"optimizer": _Boom()}, latest_checkpoint(run) / "state.pt")
    if os.path.exists("/tmp/bcbench-pwned"):
        os.remove("/tmp/bcbench-pwned")
    code = main(["train", "--resume", str(run), "--data", str(synthetic_zarr), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "refused" in err and "state.pt" in err
    assert not os.path.exists("/tmp/bcbench-pwned")  # nothing ran


def test_a_max_steps_the_epochs_never_reach_is_said(synthetic_zarr, tmp_path, capsys):
    """max_steps beyond epochs x steps per epoch cannot bind; the trainer says so rather than stopping short quietly."""
    run = new_run("cnn_mlp", "quick", tiny_overrides("cnn_mlp", epochs=1, max_steps=10**6), tmp_path / "r",
                  _opts(synthetic_zarr))
    r = prepare(run, _opts(synthetic_zarr))
    err = capsys.readouterr().err
    assert f"end training at step {r.total_steps}, before max_steps 1000000" in err
    prepare(new_run("cnn_mlp", "quick", tiny_overrides("cnn_mlp", epochs=1, max_steps=1), tmp_path / "s",
                    _opts(synthetic_zarr)), _opts(synthetic_zarr))
    assert "max_steps" not in capsys.readouterr().err  # a cap that binds is not noted


# BatchNorm (recalibrated), GroupNorm with random crops, and dropout beside BatchNorm: every RNG stream training draws
@pytest.mark.parametrize("name", ["cnn_mlp", "diffusion", "bct", "bet"])
def test_validating_every_n_steps_leaves_a_cosine_runs_weights_bit_identical(name, synthetic_zarr, tmp_path,
                                                                              one_thread):
    """`optim.val_every` moves only the epoch-end work (BN recalibration, validation): training does not read it
    unless the schedule is plateau, so the final weights, buffers and EMA equal the per-epoch run's bit for bit."""
    base = tiny_overrides(name, epochs=4, precision="fp32", schedule="cosine", ema=True)
    if name in ("bct", "bet"):
        base["dropout"] = 0.1  # the presets' dropout (the tiny networks turn it off)
    runs = {}
    for every in (None, 5):
        extra = {} if every is None else {"optim.val_every": every}
        runs[every] = new_run(name, "quick", {**base, **extra}, tmp_path / f"every-{every}", _opts(synthetic_zarr))
        s = train(runs[every], _opts(synthetic_zarr))
        assert s["stopped"] == "finished"
    per_epoch, sparse = ([m["step"] for m in read_jsonl(runs[e] / "metrics.jsonl") if "val_loss" in m]
                         for e in (None, 5))
    total, epoch = s["total_steps"], s["total_steps"] // 4
    assert per_epoch == list(range(epoch, total + 1, epoch)) and epoch != 5
    assert sparse == [*range(5, total + 1, 5), *([total] if total % 5 else [])]  # the last step always validates
    for file in ("model.safetensors", "ema.safetensors"):
        from safetensors.torch import load_file

        a, b = (load_file(str(latest_checkpoint(runs[e]) / file)) for e in (None, 5))
        assert a.keys() == b.keys()
        for k in a:
            assert torch.equal(a[k], b[k]), (file, k)


def test_val_every_steps_the_plateau_schedule_at_each_validation(synthetic_zarr, tmp_path, one_thread):
    """With the plateau schedule the scheduler steps at each validation val_every places, a cadence unlike the
    epoch's, and not at the last, off-cadence one: its patience counts validations."""
    every = 5
    over = tiny_overrides("cnn_mlp", epochs=4, precision="fp32", schedule="plateau", val_every=every)
    seen: list[tuple[int, int]] = []
    opts = dataclasses.replace(_opts(synthetic_zarr), callbacks=(lambda r: seen.append((r.state.step,
                                                                                       r.scheduler.last_epoch)),))
    run = new_run("cnn_mlp", "quick", over, tmp_path / "plateau", opts)
    s = train(run, opts)
    total = s["total_steps"]
    assert (total // 4) % every and total % every  # the epoch's cadence differs, and the last step is off it
    stepped, calls = [], 0  # ReduceLROnPlateau counts its step() calls in last_epoch, from 0
    for step, n in seen:
        if n != calls:
            stepped, calls = [*stepped, step], n
    assert stepped == list(range(every, total + 1, every)) and len(stepped) >= 2
    from bcbench.policies.checkpoint import load_state

    assert load_state(latest_checkpoint(run))["scheduler"]["last_epoch"] == total // every  # not the last one
    for bad in (0, -2, 2.5, True):
        with pytest.raises(BCBenchError, match="val_every must be a whole number >= 1"):
            new_run("cnn_mlp", "quick", {**over, "optim.val_every": bad}, tmp_path / f"bad{bad}",
                    _opts(synthetic_zarr))
