"""Per-episode results of a fixed little pipeline (train tiny policies on synthetic data, evaluate them and a
baseline), written by the code of any commit: the behaviour check of the issue-29 restructuring.

    python tests/golden/make_golden.py OUT.json      (run at 0fe1623, before the move into stage packages)
tests/test_architecture.py runs the same pipeline on today's code and compares with the committed file.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: `tests` importable

import torch
from tests.conftest import make_synthetic_buffer
from tests.tiny import tiny_overrides

try:  # after the restructuring
    from bcbench.evaluation.evaluate import EvalConfig, evaluate
    from bcbench.policies.checkpoint import configure_runner, load_runner
    from bcbench.training.loop import TrainOptions, new_run, train
except ImportError:  # before it (0fe1623)
    from bcbench.checkpoint import configure_runner, load_runner
    from bcbench.evaluate import EvalConfig, evaluate
    from bcbench.train import TrainOptions, new_run, train
from bcbench.data.replay_buffer import write_replay_buffer
from bcbench.policies import make_policy


def episodes(result: dict) -> list[dict]:
    return [{k: e[k] for k in ("seed", "score", "final_state", "length")} for e in result["episodes"]]


def pipeline() -> dict[str, list[dict]]:
    torch.set_num_threads(1)
    out: dict[str, list[dict]] = {}
    cfg = EvalConfig(episodes=3, max_steps=40, workers=1)
    out["scripted"] = episodes(evaluate(make_policy("scripted", "quick", seed=0), cfg, None, progress=False))
    with tempfile.TemporaryDirectory() as tmp:
        data = write_replay_buffer(Path(tmp) / "d.zarr", make_synthetic_buffer(), chunk=7)
        opts = TrainOptions(data=str(data), threads=1, progress=False, device="cpu")
        for name, sampler in (("cnn_mlp", None), ("diffusion", ("ddim", 2)), ("bet", None)):
            run = new_run(name, "quick", {**tiny_overrides(name, max_steps=3), "optim.precision": "fp32"},
                          Path(tmp) / name, opts)
            train(run, opts)
            runner = load_runner(run)
            configure_runner(runner, *(sampler or (None, None)), seed=0)
            out[name] = episodes(evaluate(runner, EvalConfig(episodes=2, max_steps=24, workers=1), None,
                                          progress=False))
    return out


if __name__ == "__main__":
    Path(sys.argv[1]).write_text(json.dumps(pipeline(), indent=1) + "\n")
