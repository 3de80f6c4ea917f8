"""Training samples/s of every learned policy's CPU config: the old settings beside the new, in one run.

    .venv/bin/python benchmarks/train_throughput.py [--steps 3] [--rounds 4] [--threads 2] [--policy NAME ...]
        [--ablation] [--out DIR]

old: fp32, batch 64, contiguous weights (what the trainer did before the cpu profile);
new: the config's precision (auto = bf16 autocast on CPUs with AVX512-BF16/AMX), its batch (256 in the cpu
     profile), channels-last 2-D convolutions.
One optimiser step = a batch gathered from the real training windows (when the dataset is beside the repo;
random tensors of the real shapes otherwise), forward, loss, backward, the config's optimiser, EMA if the
config keeps one, the same code as `bcbench train` (bcbench.training). Old and new run interleaved in
--rounds rounds of --steps timed steps each (after one warm-up step per round): this machine is a shared
VM whose speed drifts by tens of percent within minutes, and interleaving exposes both settings to it
alike. Median samples/s of each over all its timed steps. Stop anything else running first: timings from a
busy machine mean nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bcbench.policies import learned_policies, make_config
from bcbench.policies.config import config_to_dict
from bcbench.training import EMA, autocast, channels_last_convs, make_optimizer, resolve_precision
from bcbench.utils.io import atomic_path, write_json
from bcbench.utils.system import provenance


def get_batch(batch: int, step: int, ds) -> dict[str, torch.Tensor]:
    """Real windows (gathering them is part of a training step), else random tensors of the real shapes."""
    rng = np.random.default_rng(step)
    if ds is not None:
        return {k: torch.from_numpy(v) for k, v in ds.get_batch(rng.integers(0, len(ds), batch)).items()}
    g = torch.Generator().manual_seed(step)
    return {"image": torch.rand(batch, 2, 3, 96, 96, generator=g), "agent_pos": torch.rand(batch, 2, 2) * 2 - 1,
            "action": torch.rand(batch, 16, 2) * 2 - 1}


def step_fn(name: str, cfg, precision: str, batch: int, channels_last: bool, ds) -> Any:
    """A closure that runs one full training step and returns its time in seconds."""
    from bcbench.policies import REGISTRY

    torch.manual_seed(0)
    model = REGISTRY[name][1](cfg).train()
    if channels_last:
        channels_last_convs(model)
    opt = make_optimizer(model, cfg.optim)
    ema = EMA(model, cfg.optim.ema_power, cfg.optim.ema_max_decay) if cfg.optim.ema else None
    prec = resolve_precision(precision, torch.device("cpu"))
    count = [0]

    def step() -> float:
        count[0] += 1
        t = time.perf_counter()
        b = get_batch(batch, count[0], ds)
        with autocast(torch.device("cpu"), prec):
            loss = model.compute_loss(b)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if ema is not None:
            ema.update(model, count[0])
        return time.perf_counter() - t

    return step


def compare(name: str, settings: dict[str, tuple[Any, str, int, bool]], rounds: int, steps: int, ds
            ) -> dict[str, float]:
    """Every setting (config, precision, batch, channels-last) interleaved round by round, so that a noisy
    neighbour on a shared machine slows all alike; median samples/s of each over all its timed steps (each
    round's first step is warm-up)."""
    fns = {k: step_fn(name, cfg, prec, batch, cl, ds) for k, (cfg, prec, batch, cl) in settings.items()}
    times: dict[str, list[float]] = {k: [] for k in settings}
    for _ in range(rounds):
        for k, fn in fns.items():
            fn()
            times[k] += [fn() for _ in range(steps)]
    return {k: settings[k][2] / float(np.median(t)) for k, t in times.items()}


def ablation_settings(cfg, old_cfg, prec: str) -> dict[str, tuple[Any, str, int, bool]]:
    """The new settings with one of their three changes undone at a time: which change buys what."""
    b = cfg.optim.batch_size
    return {"new without bf16": (old_cfg, "fp32", b, True), "new at batch 64": (cfg, prec, 64, True),
            "new without channels-last": (cfg, prec, b, False)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=3, help="timed steps per setting and round")
    ap.add_argument("--rounds", type=int, default=4, help="rounds of old then new, interleaved")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--config", default="cpu", help="policy preset (default cpu)")
    ap.add_argument("--policy", action="append")
    ap.add_argument("--ablation", action="store_true",
                    help="also time the new settings with each of their changes undone (bf16, batch, layout)")
    ap.add_argument("--out", default="results/train-throughput")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    ds = None
    try:
        from bcbench.data import load_replay_buffer, make_datasets, resolve_dataset

        ds = make_datasets(load_replay_buffer(resolve_dataset(None)))[0]
    except Exception as exc:  # no dataset: random tensors of the same shapes
        print(f"(dataset not found, random batches: {exc})")
    rows = []
    print(f"| policy ({args.config}) | old: fp32, batch 64 | new: precision, batch, channels-last | speed-up |")
    print("|---|---|---|---|")
    for name in args.policy or learned_policies():
        cfg = make_config(name, args.config)
        old_cfg = dataclasses.replace(cfg, optim=dataclasses.replace(cfg.optim, batch_size=64, precision="fp32"))
        prec = resolve_precision(cfg.optim.precision, torch.device("cpu"))
        settings = {"old": (old_cfg, "fp32", 64, False), "new": (cfg, cfg.optim.precision, cfg.optim.batch_size, True)}
        if args.ablation:
            settings |= ablation_settings(cfg, old_cfg, prec)
        sps = compare(name, settings, args.rounds, args.steps, ds)
        old, new = sps.pop("old"), sps.pop("new")
        rows.append({"policy": name, "config": args.config, "old_samples_per_s": old, "new_samples_per_s": new,
                     "new_precision": prec, "new_batch": cfg.optim.batch_size, "speedup": new / old,
                     "ablation_samples_per_s": sps, "policy_config": config_to_dict(cfg)})
        more = "".join(f"; {k} {v:.0f}" for k, v in sps.items())
        print(f"| {name} | {old:.0f} | {new:.0f} ({prec}, batch {cfg.optim.batch_size}{more}) | {new / old:.2f}x |",
              flush=True)
    out = Path(args.out)
    write_json(out / "throughput.json", {"type": "train-throughput", "steps": args.steps, "rounds": args.rounds,
                                         "real_data": ds is not None,
                                         "rows": rows, **provenance("cpu")})
    cols = list(rows[0]["ablation_samples_per_s"]) if rows else []
    with atomic_path(out / "throughput.md") as tmp:
        tmp.write_text("| policy | old samples/s (fp32, batch 64) | new samples/s | precision, batch | speed-up |"
                       + "".join(f" {c} |" for c in cols) + "\n" + "|---" * (5 + len(cols)) + "|\n" + "".join(
                           f"| {r['policy']} ({r['config']}) | {r['old_samples_per_s']:.0f} | "
                           f"{r['new_samples_per_s']:.0f} | {r['new_precision']}, {r['new_batch']} | "
                           f"{r['speedup']:.2f}x |" + "".join(f" {r['ablation_samples_per_s'][c]:.0f} |" for c in cols)
                           + "\n" for r in rows))


if __name__ == "__main__":
    main()
