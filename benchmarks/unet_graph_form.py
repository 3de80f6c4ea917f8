"""Where the time of one exported U-Net step goes, and which graph form a runtime runs fastest on this CPU.

    .venv/bin/python benchmarks/unet_graph_form.py [--config paper] [--batch 1 50] [--rounds 20] [--calls 5]
                [--threads 2] [--out results/latency-graph-form]

Diffusion Policy's and flow's inference is the `denoise` graph run once per step. It is traced in two forms:
`convolution` (channels first, every layer a Conv1d / ConvTranspose1d: the form bcbench exported up to
GRAPH_FORMAT 1) and `time_last` (channels last, every convolution one fully connected product over its unfolded
input: the form exported now, bcbench.policies.unet1d). Each form is compiled by OpenVINO (fp32, static shape per
batch, as deployed) and, where installed, ONNX Runtime (fp32), and every (form, runtime, batch) is timed in
interleaved rounds (--calls calls each, in turn, so a drifting VM hits all alike). At batch 1 the floor of a step
is the weight bytes it reads over this machine's streaming bandwidth (measured in the same run); OpenVINO's own
per-operation profiler splits the time of the last timed call of each form by operation type, and the fully
connected layers' time against their weights' read time. Weights are random: they do not change the time.
Stop anything else running first. Writes graph-form.json (and a markdown table) stamped with commit and CPU.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bcbench.evaluation.floor import machine_limits
from bcbench.policies import make_policy
from bcbench.policies.unet1d import Conv1d
from bcbench.utils.io import atomic_path, write_json
from bcbench.utils.system import provenance


class Denoise(torch.nn.Module):
    """The `denoise` graph in one form."""

    def __init__(self, policy: Any, time_last: bool) -> None:
        super().__init__()
        self.policy, self.time_last = policy, time_last

    def forward(self, x: torch.Tensor, film: torch.Tensor) -> torch.Tensor:
        return self.policy.unet.forward_film(x, film, time_last=self.time_last)


@contextlib.contextmanager
def convolutions_only() -> Iterator[None]:
    """Channels first with real convolutions (not torch's CPU im2col for wide layers) while a graph is traced."""
    keep = dict(Conv1d.MATMUL_MIN_FAN_IN)
    Conv1d.MATMUL_MIN_FAN_IN.update({True: 10**9, False: 10**9})
    try:
        yield
    finally:
        Conv1d.MATMUL_MIN_FAN_IN.update(keep)


def layer_weight_bytes(policy: Any) -> dict[str, int]:
    """fp32 bytes of every weight layer of the U-Net (what one step reads at batch 1; FiLM hoisted)."""
    return {n: m.weight.numel() * 4 for n, m in policy.unet.named_modules()
            if isinstance(m, (torch.nn.Conv1d, torch.nn.ConvTranspose1d))}


def openvino_model(policy: Any, time_last: bool, inputs: tuple) -> Any:
    """The `denoise` graph in one form, converted by OpenVINO with static shapes (as deployed at one batch)."""
    import openvino as ov

    with torch.no_grad(), convolutions_only():
        model = ov.convert_model(Denoise(policy, time_last).eval(), example_input=inputs)
    model.reshape({i.get_any_name(): list(a.shape) for i, a in zip(model.inputs, inputs, strict=True)})
    return model


def compile_openvino(model: Any, threads: int) -> Any:
    """An infer request of `model` compiled as bcbench deploys fp32 (latency hint, one stream), profiling on."""
    import openvino as ov

    config = {"PERFORMANCE_HINT": "LATENCY", "NUM_STREAMS": 1, "INFERENCE_PRECISION_HINT": "f32",
              "INFERENCE_NUM_THREADS": threads, "PERF_COUNT": True}
    return ov.Core().compile_model(model, "CPU", config).create_infer_request()


def openvino_request(policy: Any, time_last: bool, inputs: tuple, threads: int) -> Any:
    return compile_openvino(openvino_model(policy, time_last, inputs), threads)


def onnxruntime_session(policy: Any, time_last: bool, inputs: tuple, threads: int, folder: Path) -> Any:
    try:
        import onnxruntime as ort
    except ImportError:
        return None
    path = folder / f"denoise-{'time_last' if time_last else 'convolution'}-b{inputs[0].shape[0]}.onnx"
    with torch.no_grad(), convolutions_only():
        torch.onnx.export(Denoise(policy, time_last).eval(), inputs, str(path), opset_version=17, dynamo=False,
                          input_names=["x", "film"])
    opts = ort.SessionOptions()
    opts.intra_op_num_threads, opts.inter_op_num_threads = threads, 1
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def runtime_versions() -> dict[str, str | None]:
    import openvino

    try:
        import onnxruntime
    except ImportError:
        onnxruntime = None
    return {"openvino": openvino.__version__, "onnxruntime": onnxruntime and onnxruntime.__version__}


def op_profile(request: Any) -> dict[str, Any]:
    """OpenVINO's per-operation times of the last call: summed by operation type, and each weight-reading node's
    time (convolution or fully connected) in graph order, to set against its layer's weight bytes."""
    by_type: collections.Counter = collections.Counter()
    nodes = []
    for p in request.get_profiling_info():
        ms = p.real_time.total_seconds() * 1e3
        by_type[p.node_type] += ms
        if p.node_type in ("FullyConnected", "Convolution", "ConvolutionBackpropData"):
            nodes.append({"node": p.node_name, "type": p.node_type, "ms": round(ms, 3)})
    return {"ms_by_op_type": {k: round(v, 3) for k, v in by_type.most_common()}, "weight_nodes": nodes}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="paper")
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 50])
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--calls", type=int, default=5, help="timed calls per setting and round (batch 1; fewer above)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="results/latency-graph-form")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    policy = make_policy("diffusion", args.config).eval()
    layers = layer_weight_bytes(policy)
    weight_bytes = sum(layers.values())
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fns: dict[str, Any] = {}
    scratch = tempfile.TemporaryDirectory(prefix="bcbench-form-")  # the ONNX files: not results
    requests = {}
    for b in args.batch:
        inputs = policy.graph_inputs(b)["denoise"]
        arrays = [a.numpy() for a in inputs]
        for time_last in (False, True):
            form = "time_last" if time_last else "convolution"
            req = openvino_request(policy, time_last, inputs, args.threads)
            fns[f"openvino-fp32 {form} b{b}"] = lambda r=req, a=arrays: r.infer(a)
            if b == 1:
                requests[form] = req
            sess = onnxruntime_session(policy, time_last, inputs, args.threads, Path(scratch.name))
            if sess is not None:
                feed = {"x": arrays[0], "film": arrays[1]}
                fns[f"onnxruntime-fp32 {form} b{b}"] = lambda s=sess, f=feed: s.run(None, f)
    limits = machine_limits()
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(args.rounds):
        for name, fn in fns.items():
            fn()  # warm-up of this round (caches, threads)
            for _ in range(args.calls if name.endswith(" b1") else 1):
                t0 = time.perf_counter()
                fn()
                times[name].append((time.perf_counter() - t0) * 1e3)
    floor_ms = weight_bytes / (limits["read_gb_per_s"] * 1e9) * 1e3
    rows = {name: {"median_ms": float(np.median(t)), "p99_ms": float(np.percentile(t, 99)), "calls": len(t),
                   **({"x_floor": float(np.median(t)) / floor_ms} if name.endswith(" b1") else {})}
            for name, t in times.items()}
    record = {"config": args.config, "layer_weight_mb": {n: b / 1e6 for n, b in layers.items()},
              "threads": args.threads, "rounds": args.rounds, "machine": limits,
              "weight_mb_per_step": weight_bytes / 1e6, "floor_ms_per_step_batch1": floor_ms, "rows": rows,
              "openvino_profile_batch1": {f: op_profile(r) for f, r in requests.items()},
              "runtimes": runtime_versions(),
              **provenance()}
    write_json(out / "graph-form.json", record)
    hw = record["hardware"]
    flags = ", ".join(f for f in hw["cpu_flags"] if f.startswith(("avx", "amx", "fma")))
    lines = [f"One {args.config}-size `denoise` step ({weight_bytes / 1e6:.0f} MB of weights), {args.threads} "
             f"threads, {hw['cpu_model']} ({flags}); floor at batch 1 {floor_ms:.2f} ms "
             f"({limits['read_gb_per_s']:.1f} GB/s)", "", "| runtime form batch | median ms | p99 ms | x floor |",
             "|---|---|---|---|"]
    for n, r in rows.items():
        ratio = f"{r['x_floor']:.2f}" if "x_floor" in r else "-"
        lines.append(f"| {n} | {r['median_ms']:.2f} | {r['p99_ms']:.2f} | {ratio} |")
    with atomic_path(out / "graph-form.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
