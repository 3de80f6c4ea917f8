"""bcbench on a GPU: tests that run where CUDA is, and are skipped elsewhere (CI has no GPU).

A GPU is lent to this project rarely and for minutes, so these are the checks worth those minutes, in pytest form
(`scripts/gpu_check.sh` is the longer check on real data): every learned policy trains on the device and its
checkpoint runs on the CPU, where most users evaluate it; a crashed run resumed on the device ends bit-identical to
an uninterrupted one (with deterministic kernels); the device's own facts reach the records.
`BCBENCH_TEST_DEVICE=cpu` runs the same tests on the CPU, to rehearse them before a GPU minute is spent.
"""

from __future__ import annotations

import os
from pathlib import Path

# cuBLAS sums deterministically only with a fixed workspace, read when its first handle is made: set before any CUDA
os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")

import numpy as np
import pytest
import torch

from bcbench.errors import BCBenchError
from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.timing import TimingConfig, latency_record
from bcbench.policies import learned_policies
from bcbench.policies.checkpoint import load_runner
from bcbench.tasks import example_for, get_task
from bcbench.training.loop import TrainOptions, new_run, train
from bcbench.utils.io import read_jsonl
from tests.tiny import checkpoint_weights, tiny_overrides

DEVICE = os.environ.get("BCBENCH_TEST_DEVICE", "cuda")
pytestmark = [pytest.mark.gpu,
              pytest.mark.skipif(DEVICE == "cuda" and not torch.cuda.is_available(), reason="no CUDA device here")]


class Crash(Exception):
    """Raised from a training callback: the process dies after a checkpoint, as a killed job would."""


def _opts(data, *callbacks) -> TrainOptions:
    return TrainOptions(data=str(data), device=DEVICE, threads=1, progress=False, callbacks=callbacks)


def _new_run(policy: str, data, out: Path, epochs: int = 2, task: str = "pusht", **optim) -> Path:
    return new_run(policy, "quick", tiny_overrides(policy, epochs=epochs, precision="fp32", **optim), out, _opts(data),
                   task=task)


def _train(policy: str, data, out: Path, epochs: int = 2, task: str = "pusht", **optim) -> Path:
    run = _new_run(policy, data, out, epochs, task, **optim)
    train(run, _opts(data))
    return run


def _chunk(runner, seed: int) -> np.ndarray:
    runner.model.reset_noise(seed)
    return runner.predict_action_chunk(example_for(runner.model, batch=2, seed=1))  # (B, pred_horizon, action_dim)


MW_TASK = "metaworld/drawer-open"


@pytest.fixture(scope="module")
def metaworld_zarr(tmp_path_factory) -> Path:
    """Two random episodes in the store format `bcbench data generate` writes for drawer-open (no MuJoCo needed to
    train on it): the shapes of a task other than Push-T's (4-D actions in [-1, 1], 4 proprioception values)."""
    from bcbench.tasks.metaworld.generate import _write_store

    rng, task = np.random.default_rng(0), get_task(MW_TASK)
    kept = [{"img": rng.integers(0, 256, (n, task.image_size, task.image_size, 3), dtype=np.uint8), "length": n,
             "seed": i, "state": rng.normal(size=(n, task.state_dim)).astype(np.float32),
             "action": rng.uniform(-1, 1, (n, task.action_dim)).astype(np.float32)} for i, n in enumerate((40, 36))]
    out = tmp_path_factory.mktemp("mw") / "drawer-open.zarr"
    _write_store(out, kept, {"format": "bcbench-metaworld-v1", "task": MW_TASK}, force=False)
    return out


@pytest.mark.parametrize("task", ["pusht", MW_TASK], ids=["pusht", "metaworld"])
@pytest.mark.parametrize("policy", learned_policies())
def test_trained_on_the_device_runs_on_the_cpu(policy, task, synthetic_zarr, metaworld_zarr, tmp_path):
    """Weights saved on the device load on the CPU; a deterministic policy predicts the same chunk on both, in the
    task's shapes (Push-T's 2-D pixels; MetaWorld's 4-D actions)."""
    data = synthetic_zarr if task == "pusht" else metaworld_zarr
    run = _train(policy, data, tmp_path / policy, task=task)
    segment = read_jsonl(run / "segments.jsonl")[-1]
    assert segment["device"].startswith(DEVICE)
    if DEVICE == "cuda":
        assert segment["gpu"] == torch.cuda.get_device_name()
    on_cpu, on_device = load_runner(run, device="cpu"), load_runner(run, device=DEVICE)
    a, b = _chunk(on_cpu, 0), _chunk(on_device, 0)
    assert a.shape == b.shape == (2, on_cpu.model.config.pred_horizon, get_task(task).action_dim), a.shape
    assert np.isfinite(a).all() and np.isfinite(b).all()
    if np.array_equal(a, _chunk(on_cpu, 1)):  # the noise seed changes nothing: the two devices must agree
        # TF32 convolutions (cuDNN's default) round to 10 mantissa bits: about 1e-3 relative, on a 512-px field
        assert np.abs(a - b).max() < 1.0, np.abs(a - b).max()


@pytest.fixture
def deterministic():
    """CUDA's default kernels sum in varying order (a tiny DP's losses part at step 3 between two runs on an H200),
    so exactness is asked of the resume with deterministic kernels, where any gap is the resume's."""
    torch.use_deterministic_algorithms(True)
    yield
    torch.use_deterministic_algorithms(False)


def test_resume_on_the_device_is_exact(synthetic_zarr, tmp_path, deterministic):
    """A diffusion run crashed after its step-6 checkpoint and resumed ends bit-identical to an uninterrupted one,
    itself identical to a rerun (the device's RNG state travels in the checkpoint)."""
    full, again = (_train("diffusion", synthetic_zarr, tmp_path / n, epochs=6, checkpoint_every=3)
                   for n in ("full", "again"))

    def crash(r) -> None:
        if r.state.step == 7:
            raise Crash

    crashed = _new_run("diffusion", synthetic_zarr, tmp_path / "crashed", epochs=6, checkpoint_every=3)
    with pytest.raises(Crash):
        train(crashed, _opts(synthetic_zarr, crash))
    train(crashed, _opts(synthetic_zarr))
    a, b, c = checkpoint_weights(full), checkpoint_weights(again), checkpoint_weights(crashed)
    for k in a:
        assert torch.equal(a[k], b[k]), f"{k}: two uninterrupted runs differ, so the kernels are not deterministic"
        assert torch.equal(a[k], c[k]), f"{k}: the resumed run left the uninterrupted one"


def test_auto_is_torch_and_latency_names_the_device(synthetic_zarr, tmp_path):
    """On a GPU `auto` is torch's fast form and an exported CPU runtime is refused; a latency record says where."""
    runner = load_runner(_train("cnn_mlp", synthetic_zarr, tmp_path / "cnn"), device=DEVICE)
    if DEVICE == "cuda":
        apply_mode(runner, "auto")
        assert runner.info.mode == "fast" and runner.info.deployment["auto"]["chosen"] == "fast"
        with pytest.raises(BCBenchError, match="runs on the CPU"):
            apply_mode(runner, "openvino-fp32")
    record = latency_record(runner, TimingConfig(warmup=1, min_calls=5, max_calls=5, min_seconds=0.0))
    for mode in ("reference", "fast"):
        assert record["modes"][mode]["median_ms"] > 0
    gpu = record["hardware"]["gpu"]
    assert gpu == torch.cuda.get_device_name() if DEVICE == "cuda" else gpu is None
