"""Where does a resumed tiny Diffusion Policy run leave an uninterrupted one? Per-step training losses of three runs.

Run from the repository root:  PYTHONPATH=src:. python results/gpu-h200/tests/diag_resume.py default|det [cuda|cpu]
`det` turns on torch.use_deterministic_algorithms (with CUBLAS_WORKSPACE_CONFIG=:4096:8 in the environment).
Each line: step, the uninterrupted run's loss, then the rerun's and the crashed-and-resumed run's difference to it.
"""

import contextlib
import pathlib
import sys
import tempfile

import torch
from tests.conftest import make_synthetic_buffer
from tests.tiny import tiny_overrides

from bcbench.data.replay_buffer import write_replay_buffer
from bcbench.training.loop import TrainOptions, new_run, train
from bcbench.utils.io import read_jsonl


class Crash(Exception):
    pass


def crash(r) -> None:
    if r.state.step == 7:  # after the step-6 checkpoint, as a killed job
        raise Crash


def main(mode: str, device: str) -> None:
    if mode == "det":
        torch.use_deterministic_algorithms(True)
    folder = pathlib.Path(tempfile.mkdtemp())
    data = str(write_replay_buffer(folder / "p.zarr", make_synthetic_buffer(), chunk=7))
    overrides = tiny_overrides("diffusion", epochs=6, checkpoint_every=3, precision="fp32")

    def opts(*callbacks) -> TrainOptions:
        return TrainOptions(data=data, device=device, threads=1, progress=False, callbacks=callbacks)

    runs = {}
    for name in ("full", "again", "crashed"):
        runs[name] = run = new_run("diffusion", "quick", overrides, folder / name, opts())
        if name == "crashed":
            with contextlib.suppress(Crash):
                train(run, opts(crash))
        train(run, opts())
    loss = {name: {m["step"]: m["train_loss"] for m in read_jsonl(run / "metrics.jsonl") if "train_loss" in m}
            for name, run in runs.items()}
    print("mode", "deterministic" if mode == "det" else "default")
    for s, ref in sorted(loss["full"].items()):
        print(s, f"{ref:.9f}", f"again {loss['again'][s] - ref:+.2e}", f"crashed {loss['crashed'][s] - ref:+.2e}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "cuda")
