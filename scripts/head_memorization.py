"""How far a base's aged chunk is from the demonstration, on its training windows and on held-out ones.

For a correction head (bcbench.policies.correction): the error the head would learn to correct, by chunk age a,
as the mean squared error (normalised units) between the base's action for t0 + a, planned from the observation
at t0, and the demonstration's action there. 512 windows of each split, one noise draw each.
    python scripts/head_memorization.py BASE_RUN OUT.json [--sampler ddim --steps 10]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from bcbench.data.sequence import make_datasets
from bcbench.evaluation.backends import run_data_split
from bcbench.policies.checkpoint import build_model
from bcbench.policies.config import config_to_dict
from bcbench.policies.correction import CorrectionConfig
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("base")
    p.add_argument("out")
    p.add_argument("--sampler", default="ddim")
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--windows", type=int, default=512)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--data", help="the demonstrations (default: the task's)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    cfg = CorrectionConfig.preset("cpu")
    cfg.base, cfg.base_sampler, cfg.base_steps = a.base, a.sampler, a.steps
    head = build_model({"policy": "correction", "config": config_to_dict(cfg)})
    split = run_data_split(a.base)  # the episodes the base trained on, and those it held out
    window = {**head.data_window(), "normalizer": head.base.normalizer}  # in the base's units, on its own split
    train, held, _ = make_datasets(head.task.demonstrations(a.data), split.get("val_fraction", 0.1),
                                   split.get("split_seed", 0), state_dim=head.state_dim, demos=split.get("demos"),
                                   **window)
    head.attach_data(train)
    rng = np.random.default_rng(0)
    out = {"base": a.base, "base_weights_sha256": head.base.info.weights_sha256,
           "sampler": a.sampler, "steps": a.steps, "windows": a.windows}
    for name, ds in (("training", train), ("held_out", held)):
        ids = rng.choice(len(ds), min(a.windows, len(ds)), replace=False)
        batch = {k: torch.from_numpy(v) for k, v in ds.get_batch(ids).items()}
        cs = head.config.obs_horizon - 1  # the chunk's index of its current step
        plan = head.cached_plans(batch["steps"][:, cs], torch.zeros(len(ids), dtype=torch.long))  # (n, Tp, A)
        err = ((plan[:, cs:] - batch["action"][:, cs:]) ** 2).mean(-1)  # (n, Tp - cs): ages 0 .. Tp - 1 - cs
        out[name] = {"mse": float(err.mean()), "mse_by_age": [round(float(x), 6) for x in err.mean(0)]}
        print(f"{name}: mse {out[name]['mse']:.4f}; by age {out[name]['mse_by_age']}")
    write_json(a.out, {**out, **provenance("cpu")})


if __name__ == "__main__":
    main()
