"""A trained correction head, open loop: its error against its own target on held-out windows, by chunk age.

For each age a, on 64 windows of the head's validation split (noise draw 0): the mean squared error (normalised
units) of the stale chunk's action (a zero residual) and of the corrected action against the head's target, the
mean residual size in pixels, and the largest difference between the residual the runner computes from raw
observations (`CorrectionRunner.correct`, what the controller calls) and the training path's.
    python scripts/head_open_loop.py HEAD_RUN OUT.json [--data DEMOS]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from bcbench.data.sequence import make_datasets
from bcbench.policies.checkpoint import load_correction
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("head")
    p.add_argument("out")
    p.add_argument("--data", help="the demonstrations, for a head trained on them (default: the task's)")
    p.add_argument("--windows", type=int, default=64)
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    head = load_correction(a.head)
    m, c = head.model, head.model.config
    buf = m.training_data(a.data)
    train, val, _ = make_datasets(buf, 0.1, 0, state_dim=m.state_dim, **m.data_window())
    m.attach_data(train)
    ids = np.linspace(0, len(val) - 1, min(a.windows, len(val))).astype(int)
    b = {k: torch.from_numpy(v) for k, v in val.get_batch(ids).items()}
    steps, n = b["steps"], len(ids)
    k = torch.zeros(n, dtype=torch.long)
    out = {"head": a.head, "head_weights_sha256": head.weights_sha256, "target": c.target, "by_age": []}
    for age in range(c.max_age + 1):
        ages = torch.full((n,), age)
        t = m.terms(b, ages, k)  # the head's inputs and target, as training draws them
        planned, target = t["planned"], t["target"]
        with torch.no_grad():
            res = m.residual(t["feats"], planned, ages, t["index"])
        cols = t["index"][:, None] + torch.arange(1 - c.obs_horizon, 1)  # (n, To): the frames ending at t0 + a
        frames = steps[torch.arange(n)[:, None], cols].numpy()
        planned_px = head.normalizer.unnormalize("action", planned).numpy()
        ran = head.correct({"image": buf.images[frames], "agent_pos": buf.state[frames][..., : m.state_dim]},
                           planned_px, ages.numpy(), t["index"].numpy()) - planned_px
        trained = (head.normalizer.unnormalize("action", planned + res)
                   - head.normalizer.unnormalize("action", planned)).numpy()
        row = {"age": age, "mse_stale": float(((target - planned) ** 2).mean()),
               "mse_corrected": float(((target - planned - res) ** 2).mean()),
               "residual_px": float(np.linalg.norm(ran, axis=-1).mean()),
               "runner_minus_training_px": float(np.abs(ran - trained).max())}
        out["by_age"].append(row)
        print(row)
    write_json(a.out, {**out, **provenance("cpu")})


if __name__ == "__main__":
    main()
