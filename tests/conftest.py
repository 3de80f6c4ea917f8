"""Shared fixtures: a tiny synthetic replay buffer on disk, and the real dataset when it is beside us."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
# MuJoCo picks its GL backend once, when first imported, by whichever test module that is: headless EGL
os.environ.setdefault("MUJOCO_GL", "egl")
# Tiny models gain nothing from threads, and OpenMP threads spinning against another busy process (a
# study running beside the tests) can slow small ops 100-fold. Subprocesses inherit this too.
os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch

torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))

from bcbench.data.replay_buffer import ReplayBuffer, write_replay_buffer  # noqa: E402
from bcbench.utils.system import restore_scheduling, scheduling  # noqa: E402

EPISODE_LENGTHS = (5, 20, 12)


def make_synthetic_buffer(lengths: tuple[int, ...] = EPISODE_LENGTHS, seed: int = 0) -> ReplayBuffer:
    """Random but well-formed data; images hold non-integers too, to exercise the uint8 rounding."""
    rng = np.random.default_rng(seed)
    n = sum(lengths)
    images = rng.uniform(-3, 258, size=(n, 96, 96, 3)).astype(np.float32)
    images[:, :2] = np.round(images[:, :2])
    state = rng.uniform(0, 512, size=(n, 5)).astype(np.float32)
    state[:, 0] = np.arange(n)  # agent x = global step index: makes window checks readable
    action = rng.uniform(0, 512, size=(n, 2)).astype(np.float32)
    action[:, 0] = np.arange(n)
    return ReplayBuffer(
        state=state, action=action, episode_ends=np.cumsum(lengths).astype(np.int64), images=images,
        keypoint=rng.uniform(0, 512, size=(n, 9, 2)).astype(np.float32),
        n_contacts=rng.integers(0, 3, size=(n, 1)).astype(np.float32),
    )


@pytest.fixture(scope="session")
def synthetic_buffer() -> ReplayBuffer:
    return make_synthetic_buffer()


@pytest.fixture(scope="session")
def synthetic_zarr(tmp_path_factory: pytest.TempPathFactory, synthetic_buffer: ReplayBuffer) -> Path:
    path = tmp_path_factory.mktemp("data") / "pusht_cchi_v7_replay.zarr"
    # chunk of 7 steps: several chunks, and the last one partial
    return write_replay_buffer(path, synthetic_buffer, chunk=7)


@pytest.fixture(scope="session")
def real_zarr() -> Path:
    from bcbench.data.paths import candidate_paths

    env = os.environ.get("BCBENCH_DATA")
    for cand in ([Path(env)] if env else []) + candidate_paths():
        if cand.is_dir():
            return cand
    pytest.skip("the real Push-T dataset is not beside the repository")


@pytest.fixture(autouse=True)
def scheduling_unchanged():
    """A test that leaves this worker's scheduling policy changed fails, and the policy is put back: a worker left at
    SCHED_FIFO 99 (SVT-AV1's video encoder did it, as root) runs every later test, and every process they start,
    real-time, which starved the other worker's wall-clock steps and let Chromium spin past its timeout."""
    was = scheduling()
    yield
    now = scheduling()
    if restore_scheduling(was):
        pytest.fail(f"the test changed this process's scheduling (policy, priority) from {was} to {now}")


@pytest.fixture(autouse=True)
def cpu_unless_a_gpu_test(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    """The suite describes the CPU, CI's machine. On a machine with CUDA, `--device auto` would move the tests'
    models there and break their comparisons with CPU tensors and CPU runtimes (seen on a lent H200: 9 tests), so
    CUDA is hidden from every test not marked `gpu` (tests/test_gpu.py asks for the device itself): from bcbench's
    code in this process, and from the processes a test starts (a subprocess that trained on the GPU while its test
    resumed on the CPU broke the SIGKILL test there). The variable does not reach this process's own CUDA, which
    counted its devices when test_gpu.py was collected."""
    if request.node.get_closest_marker("gpu") is None:
        monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
        monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")


@pytest.fixture(scope="session")
def knn_site(tmp_path_factory):
    """The worked example plug-in (examples/knn_policy) installed with pip into a folder put on PYTHONPATH: the venv
    itself stays as it is. Shared by the plug-in tests (tests/test_outside.py, tests/test_choose_command.py)."""
    import subprocess
    import sys

    site = tmp_path_factory.mktemp("site")
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--target",
                    str(site), str(Path(__file__).resolve().parents[1] / "examples" / "knn_policy")],
                   check=True, timeout=300)
    return site
