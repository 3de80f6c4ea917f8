"""Training on several processes (torchrun, DDP over gloo): the same losses as one process on the same global
batch, and a resumed run ends where an uninterrupted one does."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest
import torch

from bcbench.policies.checkpoint import latest_checkpoint
from tests.tiny import checkpoint_weights, tiny_overrides

BIN = os.path.dirname(sys.executable)
# the tiny Diffusion Policy without random crop (crop offsets are drawn per shard; noise and t per row)
SETS = {**tiny_overrides("diffusion", max_steps=4, batch_size=8, checkpoint_every=2, precision="fp32",
                                    epochs=20), "crop": None}


def _train(run, data, procs: int | None = None, resume: bool = False):
    sets = [a for k, v in SETS.items() for a in ("--set", f"{k}={json.dumps(v)}")]
    args = ["--resume", str(run)] if resume else ["--policy", "diffusion", "--out", str(run), *sets]
    cmd = [os.path.join(BIN, "bcbench"), "train", *args, "--data", str(data), "--quiet", "--threads", "1"]
    if procs:
        cmd = [os.path.join(BIN, "torchrun"), "--nproc-per-node", str(procs), "--master-port", "29517",
               "-m", "bcbench.cli.main", *cmd[1:]]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]


def _losses(run):
    return [m["train_loss"] for m in map(json.loads, (run / "metrics.jsonl").read_text().splitlines())
            if "train_loss" in m]


def test_two_processes_train_like_one(synthetic_zarr, tmp_path):
    _train(tmp_path / "one", synthetic_zarr)
    _train(tmp_path / "two", synthetic_zarr, procs=2)
    one, two = _losses(tmp_path / "one"), _losses(tmp_path / "two")
    assert len(one) == len(two) == 4
    assert one == pytest.approx(two, rel=1e-5, abs=1e-7)  # float tolerance: the gradient sums in another order
    for k, v in checkpoint_weights(tmp_path / "one").items():
        torch.testing.assert_close(checkpoint_weights(tmp_path / "two")[k], v, rtol=1e-3, atol=2e-5)

    # a crash after the step-2 checkpoint: drop the final one, resume on two processes, end at the same weights
    # (to float tolerance: Adam divides by sqrt(v), which magnifies the last bits of tiny gradients)
    ckpts = tmp_path / "two" / "checkpoints"
    shutil.rmtree(latest_checkpoint(tmp_path / "two"))
    (ckpts / "latest.json").write_text(json.dumps({"step": 2, "dir": "step_0000002"}))
    (tmp_path / "two" / "train_summary.json").unlink()
    assert latest_checkpoint(tmp_path / "two").name == "step_0000002"
    _train(tmp_path / "two", synthetic_zarr, procs=2, resume=True)
    assert latest_checkpoint(tmp_path / "two").name == "step_0000004"
    for k, v in checkpoint_weights(tmp_path / "one").items():
        torch.testing.assert_close(checkpoint_weights(tmp_path / "two")[k], v, rtol=1e-3, atol=2e-5)
