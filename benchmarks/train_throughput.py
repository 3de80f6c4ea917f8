"""Training samples/s of every learned policy's CPU config: the old settings beside the new, in one run.

    .venv/bin/python benchmarks/train_throughput.py [--steps 3] [--rounds 4] [--threads 2] [--policy NAME ...]
        [--ablation] [--old-commit 1cf7ee4] [--out DIR]

old: fp32, batch 64, contiguous weights (the settings the trainer used before the cpu profile), run by
     today's training code;
new: the config's precision (auto = bf16 autocast on CPUs with AVX512-BF16/AMX), its batch (256 in the cpu
     profile), channels-last 2-D convolutions.
--ablation adds the new settings with one change undone at a time (what each change buys). --old-commit
adds the trainer of an older commit (1cf7ee4: the last before the cpu profile) at its settings, fp32 and
batch 64, on the same network: its own model, loss and crop, optimiser and EMA code, run in a subprocess
(old_trainer_step.py) interleaved with the rest. "old" isolates what the settings buy; "old trainer" adds what
the training code's own changes bought (vectorised crop, fused EMA and optimiser, U-Net convolutions as
matrix products, one permutation per epoch).
One optimiser step = a batch gathered from the real training windows (when the dataset is beside the repo;
random tensors of the real shapes otherwise), forward, loss, backward, the config's optimiser, EMA if the
config keeps one, the same code as `bcbench train` (bcbench.training.parts). Old and new run interleaved in
--rounds rounds of --steps timed steps each (after one warm-up step per round): this machine is a shared
VM whose speed drifts by tens of percent within minutes, and interleaving exposes both settings to it
alike. Median samples/s of each over all its timed steps. Like `bcbench train`, the process first makes
malloc keep freed memory (bcbench.training.keep_freed_memory), so every setting in it, old ones included,
runs with it; the old trainer's subprocess runs without it, as that trainer did. Stop anything else running
first: timings from a busy machine mean nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bcbench.policies import learned_policies, make_config
from bcbench.policies.config import config_to_dict
from bcbench.training.parts import (
    EMA,
    autocast,
    channels_last_convs,
    keep_freed_memory,
    make_optimizer,
    resolve_precision,
)
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
        with torch.profiler.record_function("data: gather batch"):  # a label for train_profile.py; free otherwise
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


def old_trainer_fn(name: str, cfg, commit_src: Path, threads: int) -> Any:
    """A closure timing one step of an older commit's trainer (fp32, batch 64, its own model and loss code) on
    the same network as `cfg`, run by old_trainer_step.py in a subprocess with that commit's code; None where
    that commit cannot build it."""
    import json
    import os
    import subprocess
    import sys

    from bcbench.data import resolve_dataset

    net = {k: v for k, v in config_to_dict(cfg).items() if k != "optim"}
    net |= {f"optim.{k}": v for k, v in config_to_dict(cfg)["optim"].items() if k not in ("batch_size", "precision")}
    env = {**os.environ, "PYTHONPATH": str(commit_src / "src"), "BCBENCH_DATA": str(resolve_dataset(None))}
    proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name("old_trainer_step.py")), name,
                             json.dumps(net), "64", str(threads)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=env)
    first = json.loads(proc.stdout.readline() or '{"error": "the worker exited"}')
    if "error" in first:
        print(f"(no old-trainer timing for {name}: {first['error']})")
        return None

    def step() -> float:
        proc.stdin.write("1\n")
        proc.stdin.flush()
        line = proc.stdout.readline()
        if not line:
            raise SystemExit(f"error: the old trainer's worker for {name} exited (code {proc.wait()})")
        return json.loads(line)[0]

    return step


def load_train_windows() -> Any:
    """The real training windows when the dataset is beside the repo, else None (random batches)."""
    try:
        from bcbench.data import load_replay_buffer, make_datasets, resolve_dataset

        return make_datasets(load_replay_buffer(resolve_dataset(None)))[0]
    except Exception as exc:  # no dataset: random tensors of the same shapes
        print(f"(dataset not found, random batches: {exc})")
        return None


def checkout_src(commit: str, dest: Path) -> Path:
    """The `src` tree of a commit of this repository, extracted into dest (no worktree, no checkout)."""
    import subprocess

    repo = Path(__file__).resolve().parents[1]
    archive = subprocess.run(["git", "-C", str(repo), "archive", commit, "src"], capture_output=True)
    if archive.returncode:
        raise SystemExit(f"error: cannot read commit {commit}: {archive.stderr.decode().strip()}")
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True)
    return dest


def compare(settings: dict[str, tuple[int, Callable[[], float]]], rounds: int, steps: int) -> dict[str, float]:
    """Every setting (its batch, a closure timing one step) interleaved round by round, so that a noisy
    neighbour on a shared machine slows all alike; median samples/s of each over all its timed steps (each
    round's first step is warm-up)."""
    times: dict[str, list[float]] = {k: [] for k in settings}
    for _ in range(rounds):
        for k, (_, fn) in settings.items():
            fn()
            times[k] += [fn() for _ in range(steps)]
    return {k: settings[k][0] / float(np.median(t)) for k, t in times.items()}


def ablation_settings(cfg, old_cfg, prec: str) -> dict[str, tuple[Any, str, int, bool]]:
    """The new settings with one of their three changes undone at a time: which change buys what."""
    b = cfg.optim.batch_size
    return {"new without bf16": (old_cfg, "fp32", b, True), "new at batch 64": (cfg, prec, 64, True),
            "new without channels-last": (cfg, prec, b, False)}


def markdown(rows: list[dict[str, Any]]) -> str:
    """The results table: old, new and their ratio, then any extra setting's samples/s ('-' where not run)."""
    extra = list(dict.fromkeys(c for r in rows for c in r["ablation_samples_per_s"]))
    trainer = any("speedup_vs_old_trainer" in r for r in rows)
    head = ["policy", "old samples/s (fp32, batch 64)", "new samples/s", "precision, batch", "speed-up", *extra]
    head += ["new / old trainer"] * trainer
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for r in rows:
        cells = [f"{r['policy']} ({r['config']})", f"{r['old_samples_per_s']:.0f}", f"{r['new_samples_per_s']:.0f}",
                 f"{r['new_precision']}, {r['new_batch']}", f"{r['speedup']:.2f}x"]
        cells += [f"{r['ablation_samples_per_s'][c]:.0f}" if c in r["ablation_samples_per_s"] else "-" for c in extra]
        if trainer:
            cells.append(f"{r['speedup_vs_old_trainer']:.2f}x" if "speedup_vs_old_trainer" in r else "-")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=3, help="timed steps per setting and round")
    ap.add_argument("--rounds", type=int, default=4, help="rounds of old then new, interleaved")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--config", default="cpu", help="policy preset (default cpu)")
    ap.add_argument("--policy", action="append")
    ap.add_argument("--ablation", action="store_true",
                    help="also time the new settings with each of their changes undone (bf16, batch, layout)")
    ap.add_argument("--old-commit", help="also time this older commit's trainer (its model, loss, optimiser and EMA "
                    "code; fp32, batch 64) on the same network, e.g. the one before the cpu profile: 1cf7ee4")
    ap.add_argument("--out", default="results/train-throughput")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    keeps_freed = keep_freed_memory()  # as `bcbench train` does on a CPU: for every setting of this process
    ds = load_train_windows()
    old_src = None
    if args.old_commit:
        import tempfile

        old_src = checkout_src(args.old_commit, Path(tempfile.mkdtemp(prefix="bcbench-old-")))
    rows = []
    print(f"| policy ({args.config}) | old: fp32, batch 64 | new: precision, batch, channels-last | speed-up |")
    print("|---|---|---|---|")
    for name in args.policy or learned_policies():
        cfg = make_config(name, args.config)
        old_cfg = dataclasses.replace(cfg, optim=dataclasses.replace(cfg.optim, batch_size=64, precision="fp32"))
        prec = resolve_precision(cfg.optim.precision, torch.device("cpu"))
        specs = {"old": (old_cfg, "fp32", 64, False), "new": (cfg, cfg.optim.precision, cfg.optim.batch_size, True)}
        if args.ablation:
            specs |= ablation_settings(cfg, old_cfg, prec)
        settings = {k: (batch, step_fn(name, c, p, batch, cl, ds)) for k, (c, p, batch, cl) in specs.items()}
        trainer_fn = old_trainer_fn(name, cfg, old_src, args.threads) if old_src else None
        if trainer_fn is not None:
            settings[f"old trainer ({args.old_commit[:7]})"] = (64, trainer_fn)
        sps = compare(settings, args.rounds, args.steps)
        old, new = sps.pop("old"), sps.pop("new")
        rows.append({"policy": name, "config": args.config, "old_samples_per_s": old, "new_samples_per_s": new,
                     "new_precision": prec, "new_batch": cfg.optim.batch_size, "speedup": new / old,
                     "ablation_samples_per_s": sps, "policy_config": config_to_dict(cfg)})
        trainer = next((v for k, v in sps.items() if k.startswith("old trainer")), None)
        if trainer is not None:
            rows[-1]["speedup_vs_old_trainer"] = new / trainer
        more = "".join(f"; {k} {v:.0f}" for k, v in sps.items())
        more += f"; {new / trainer:.2f}x the old trainer" if trainer is not None else ""
        print(f"| {name} | {old:.0f} | {new:.0f} ({prec}, batch {cfg.optim.batch_size}{more}) | {new / old:.2f}x |",
              flush=True)
    out = Path(args.out)
    write_json(out / "throughput.json", {"type": "train-throughput", "steps": args.steps, "rounds": args.rounds,
                                         "old_commit": args.old_commit,
                                         "real_data": ds is not None, "malloc_keeps_freed": keeps_freed,
                                         "rows": rows, **provenance("cpu")})
    with atomic_path(out / "throughput.md") as tmp:
        tmp.write_text(markdown(rows))


if __name__ == "__main__":
    main()
