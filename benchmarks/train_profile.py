"""Where a training step's time goes: one policy's cpu config at its new settings, profiled by op family.

    .venv/bin/python benchmarks/train_profile.py [--policy diffusion] [--steps 4] [--threads 2] [--out DIR]

The step is train_throughput.py's (the same closure: the batch gathered from the real training windows,
forward under the config's precision, backward, optimiser, EMA). torch.profiler's self CPU time of every op
is summed into families (convolution forward and backward, matrix products, normalisation, activations,
pooling, crop and im2col, copies and casts, element-wise, optimiser and EMA, gathering the batch), so the
table says which kind of work a faster trainer would have to shrink. Page faults and kernel time per step
come from getrusage around the same steps. It answers "why not faster?", not "how fast?": profiling costs
time, so samples/s come from train_throughput.py. Stop anything else running first.
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path
from typing import Any

import torch
from torch.profiler import ProfilerActivity, profile
from train_throughput import load_train_windows, step_fn

from bcbench.policies import make_config
from bcbench.training.parts import keep_freed_memory, resolve_precision
from bcbench.utils.io import atomic_path, write_json
from bcbench.utils.system import provenance

# (family, op-name prefixes), first match wins; the op names are aten's (and the batch gather's label)
FAMILIES: list[tuple[str, tuple[str, ...]]] = [
    ("convolution backward", ("aten::convolution_backward",)),
    ("convolution forward", ("aten::mkldnn_convolution", "aten::_convolution", "aten::convolution")),
    ("matrix products (linear layers, U-Net convolutions as im2col @ W)", (
        "aten::mm", "aten::addmm", "aten::bmm", "aten::matmul", "aten::linear", "aten::baddbmm")),
    ("normalisation fwd+bwd (GroupNorm, BatchNorm, LayerNorm)", (
        "aten::native_group_norm", "aten::native_batch_norm", "aten::native_layer_norm", "aten::_batch_norm")),
    ("activations fwd+bwd (ReLU, Mish, GELU)", (
        "aten::mish", "aten::threshold_backward", "aten::clamp_min", "aten::relu", "aten::gelu", "aten::silu")),
    ("pooling fwd+bwd", ("aten::max_pool", "aten::avg_pool", "aten::adaptive_avg_pool", "aten::mean")),
    ("random crop and im2col (unfold, index)", ("aten::unfold", "aten::index", "aten::im2col")),
    ("copies, casts, fills, allocation", ("aten::copy_", "aten::_to_copy", "aten::fill_", "aten::zero_",
                                          "aten::contiguous", "aten::clone", "aten::empty")),
    ("optimiser and EMA", ("aten::_fused_adam", "aten::lerp", "aten::_foreach", "Optimizer.")),
    ("gathering the batch (numpy)", ("data: gather batch",)),
    ("element-wise and reductions", ("aten::add", "aten::mul", "aten::sub", "aten::div", "aten::sum",
                                     "aten::mse_loss", "aten::pow", "aten::exp", "aten::sin", "aten::cos")),
]


def family(op: str) -> str:
    return next((f for f, prefixes in FAMILIES if op.startswith(prefixes)), "other")


def profile_steps(step, steps: int) -> tuple[dict[str, float], dict[str, float], float]:
    """(ms per step by family, ms per step of the 12 costliest ops, wall ms per step under the profiler)."""
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        t = time.perf_counter()
        for _ in range(steps):
            step()
        wall = (time.perf_counter() - t) / steps * 1e3
    ops = {e.key: e.self_cpu_time_total / 1e3 / steps for e in prof.key_averages()}
    fams: dict[str, float] = {}
    for op, ms in ops.items():
        f = family(op)
        fams[f] = fams.get(f, 0.0) + ms
    top = dict(sorted(ops.items(), key=lambda kv: -kv[1])[:12])
    return dict(sorted(fams.items(), key=lambda kv: -kv[1])), top, wall


def markdown(r: dict[str, Any]) -> str:
    total = sum(r["families_ms_per_step"].values())
    lines = [f"{r['policy']} ({r['config']}), batch {r['batch']}, {r['precision']}, channels-last, "
             f"{r['threads']} threads: {r['wall_ms_per_step_unprofiled']:.0f} ms a step unprofiled "
             f"({r['batch'] / r['wall_ms_per_step_unprofiled'] * 1e3:.0f} samples/s), "
             f"{r['minor_faults_per_step']:.0f} page faults and {r['kernel_ms_per_step']:.0f} ms in the kernel a step.",
             "", "| op family | ms per step (self CPU) | share |", "|---|---|---|"]
    lines += [f"| {f} | {ms:.1f} | {ms / total:.0%} |" for f, ms in r["families_ms_per_step"].items()]
    lines += ["", "| costliest ops | ms per step |", "|---|---|"]
    lines += [f"| `{op}` | {ms:.1f} |" for op, ms in r["top_ops_ms_per_step"].items()]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--policy", default="diffusion")
    ap.add_argument("--config", default="cpu")
    ap.add_argument("--steps", type=int, default=4, help="steps timed, then profiled (after 2 warm-up steps)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="results/train-throughput")
    args = ap.parse_args()
    if args.steps < 1:
        raise SystemExit("error: --steps must be >= 1")
    torch.set_num_threads(args.threads)
    keep_freed_memory()  # as `bcbench train` does on a CPU
    cfg = make_config(args.policy, args.config)
    batch, prec = cfg.optim.batch_size, resolve_precision(cfg.optim.precision, torch.device("cpu"))
    step = step_fn(args.policy, cfg, cfg.optim.precision, batch, True, load_train_windows())
    step(), step()  # warm-up: oneDNN picks and caches its kernels
    before = resource.getrusage(resource.RUSAGE_SELF)
    wall = sum(step() for _ in range(args.steps)) / args.steps * 1e3
    after = resource.getrusage(resource.RUSAGE_SELF)
    fams, top, wall_prof = profile_steps(step, args.steps)
    r = {"type": "train-profile", "policy": args.policy, "config": args.config, "batch": batch, "precision": prec,
         "steps": args.steps, "threads": torch.get_num_threads(), "wall_ms_per_step_unprofiled": wall,
         "wall_ms_per_step_profiled": wall_prof,
         "minor_faults_per_step": (after.ru_minflt - before.ru_minflt) / args.steps,
         "kernel_ms_per_step": (after.ru_stime - before.ru_stime) / args.steps * 1e3,
         "families_ms_per_step": fams, "top_ops_ms_per_step": top, **provenance("cpu")}
    out = Path(args.out)
    write_json(out / f"profile-{args.policy}.json", r)
    with atomic_path(out / f"profile-{args.policy}.md") as tmp:
        tmp.write_text(markdown(r))
    print(markdown(r))


if __name__ == "__main__":
    main()
