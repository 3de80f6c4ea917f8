"""Which matrix-product kernel streams a U-Net's fp32 weights fastest at 4-16 rows in OpenVINO (issue 28).

    .venv/bin/python benchmarks/fc_kernel.py [--config paper] [--rounds 20] [--threads 2] [--out DIR]

OpenVINO runs every fully connected layer of bcbench's exported `denoise` graph with MLAS's sgemm (exec type
`gemm_mlas_f32`), which reads the U-Net's weights below the machine's streaming rate (results/latency-graph-form).
OpenVINO picks MLAS only for a layer with no fused post-operation; one fused no-op, a clamp to the float range,
moves the layer to oneDNN's brgemm kernels (`brgemm_avx512_f32`, `brgconv_avx512_1x1_f32` on AVX-512) with the same
arithmetic. This measures both, interleaved:
- per layer shape of the paper-size U-Net (rows x fan-in x fan-out), a chain of distinct layers holding ~250 MB
  of weights (beyond any cache), each kernel's weight-streaming rate, torch's F.linear beside them;
- one whole `denoise` step (the time_last graph as bcbench exports it) in both forms: median, p90, the outputs'
  distance to torch, and the profiler's fully connected time.
Stop anything else running first. Writes fc-kernel.json and fc-kernel.md, stamped with commit and CPU.
"""

from __future__ import annotations

import argparse
import collections
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from unet_graph_form import compile_openvino, layer_weight_bytes, openvino_model

from bcbench.evaluation.floor import machine_limits
from bcbench.policies import make_policy
from bcbench.utils.io import atomic_path, write_json
from bcbench.utils.system import provenance

SHAPES = [(4, 5120, 1024), (8, 2560, 512), (16, 1280, 256)]  # (rows = time steps, Cin * 5, Cout) per U-Net level
CHAIN_MB = 250
FMAX = float(np.finfo(np.float32).max)


def clamp_fully_connected(model: Any) -> int:
    """Insert a no-op Clamp(-FLT_MAX, FLT_MAX) after every constant-weight MatMul (after its bias Add if it has
    one): OpenVINO fuses it as a post-operation, which rules MLAS out for that layer. Returns how many."""
    import openvino.opset13 as ops

    count = 0
    for op in model.get_ordered_ops():
        if op.get_type_name() != "MatMul" or op.input_value(1).get_node().get_type_name() != "Constant":
            continue
        target, users = op, list(op.output(0).get_target_inputs())
        if len(users) == 1 and users[0].get_node().get_type_name() == "Add":
            target = users[0].get_node()
        consumers = list(target.output(0).get_target_inputs())
        clamp = ops.clamp(target.output(0), -FMAX, FMAX)
        for c in consumers:
            c.replace_source_output(clamp.output(0))
        count += 1
    model.validate_nodes_and_infer_types()
    return count


def fc_profile(request: Any) -> dict[str, Any]:
    fcs = [p for p in request.get_profiling_info() if p.node_type == "FullyConnected"]
    return {"exec_types": sorted({p.exec_type for p in fcs}), "layers": len(fcs),
            "ms": sum(p.real_time.total_seconds() for p in fcs) * 1e3}


def chain_model(rows: int, fan_in: int, fan_out: int, layers: int, rng: np.random.Generator) -> tuple[Any, list]:
    """`layers` distinct fully connected layers reading one input (rows, fan_in), outputs concatenated."""
    import openvino as ov
    import openvino.opset13 as ops

    x = ops.parameter([rows, fan_in], ov.Type.f32, name="x")
    weights = [rng.standard_normal((fan_out, fan_in), dtype=np.float32) * 0.01 for _ in range(layers)]
    outs = [ops.add(ops.matmul(x, ops.constant(w), False, True), ops.constant(np.zeros(fan_out, np.float32)))
            for w in weights]
    return ov.Model([ops.concat(outs, 1)], [x]), weights


def timed(fns: dict[str, Any], rounds: int, calls: int) -> dict[str, list[float]]:
    """Interleaved: each round runs every function (2 warm-up calls after the switch, then `calls` timed),
    in an order reversed every other round."""
    times: dict[str, list[float]] = collections.defaultdict(list)
    for r in range(rounds):
        for name in (list(fns) if r % 2 == 0 else list(fns)[::-1]):
            fns[name](), fns[name]()
            for _ in range(calls):
                t0 = time.perf_counter()
                fns[name]()
                times[name].append((time.perf_counter() - t0) * 1e3)
    return times


def layer_shapes(threads: int, rounds: int) -> list[dict[str, Any]]:
    rng = np.random.default_rng(0)
    rows_out = []
    for rows, fan_in, fan_out in SHAPES:
        layers = max(1, int(CHAIN_MB * 1e6 / (fan_in * fan_out * 4)))
        mb = layers * fan_in * fan_out * 4 / 1e6
        model, weights = chain_model(rows, fan_in, fan_out, layers, rng)
        x = rng.standard_normal((rows, fan_in), dtype=np.float32)
        mlas = compile_openvino(model, threads)
        clamp_fully_connected(model)
        onednn = compile_openvino(model, threads)
        wt, xt = [torch.from_numpy(w) for w in weights], torch.from_numpy(x)

        def torch_chain(xt: torch.Tensor = xt, wt: list = wt) -> None:
            with torch.inference_mode():
                torch.cat([torch.nn.functional.linear(xt, w) for w in wt], 1)

        fns = {"openvino mlas": lambda r=mlas, x=x: r.infer([x]),
               "openvino onednn": lambda r=onednn, x=x: r.infer([x]), "torch": torch_chain}
        limits = machine_limits()
        times = timed(fns, rounds, 3)
        rows_out.append({"rows": rows, "fan_in": fan_in, "fan_out": fan_out, "layers": layers, "weights_mb": mb,
                         "read_gb_per_s": limits["read_gb_per_s"],
                         "exec_types": {"openvino mlas": fc_profile(mlas)["exec_types"],
                                        "openvino onednn": fc_profile(onednn)["exec_types"]},
                         "median_ms": {k: float(np.median(t)) for k, t in times.items()},
                         "gb_per_s": {k: mb / float(np.median(t)) for k, t in times.items()}})
    return rows_out


def unet_step(config: str, threads: int, rounds: int) -> dict[str, Any]:
    torch.manual_seed(0)
    policy = make_policy("diffusion", config).eval()
    inputs = policy.graph_inputs(1)["denoise"]
    arrays = [a.numpy() for a in inputs]
    weight_mb = sum(layer_weight_bytes(policy).values()) / 1e6
    requests = {}
    for form in ("mlas", "onednn"):
        model = openvino_model(policy, True, inputs)  # the time_last form bcbench exports
        if form == "onednn":
            clamp_fully_connected(model)
        requests[form] = compile_openvino(model, threads)
    with torch.no_grad():
        ref = policy.unet.forward_film(*inputs, time_last=True).numpy()
    diff = {k: float(np.abs(r.infer(arrays)[0] - ref).max()) for k, r in requests.items()}
    before = machine_limits()
    times = timed({k: (lambda r=r: r.infer(arrays)) for k, r in requests.items()}, rounds, 5)
    after = machine_limits()
    floor_ms = weight_mb / max(before["read_gb_per_s"], after["read_gb_per_s"])
    return {"weights_mb": weight_mb, "limits": [before, after], "floor_ms": floor_ms, "max_abs_diff_vs_torch": diff,
            "median_ms": {k: float(np.median(t)) for k, t in times.items()},
            "p90_ms": {k: float(np.percentile(t, 90)) for k, t in times.items()},
            "calls": {k: len(t) for k, t in times.items()},
            "fully_connected": {k: fc_profile(r) for k, r in requests.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="paper")
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="results/latency-graph-form/fc-kernel")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    shapes = layer_shapes(args.threads, max(3, args.rounds // 4))
    step = unet_step(args.config, args.threads, args.rounds)
    record = {"config": args.config, "threads": args.threads, "rounds": args.rounds, "layer_shapes": shapes,
              "unet_step": step, **provenance()}
    write_json(out / "fc-kernel.json", record)
    hw = record["hardware"]
    flags = ", ".join(f for f in hw["cpu_flags"] if f.startswith(("avx", "amx", "fma")))
    lines = [f"{hw['cpu_model']} ({flags}), {args.threads} threads; weight-streaming rate (GB/s) per kernel", "",
             "| rows x fan-in x fan-out | layers (MB) | streaming read | OpenVINO MLAS | OpenVINO oneDNN | torch |",
             "|---|---|---|---|---|---|"]
    for s in shapes:
        g = s["gb_per_s"]
        lines.append(f"| {s['rows']} x {s['fan_in']} x {s['fan_out']} | {s['layers']} ({s['weights_mb']:.0f}) | "
                     f"{s['read_gb_per_s']:.1f} | {g['openvino mlas']:.1f} | {g['openvino onednn']:.1f} | "
                     f"{g['torch']:.1f} |")
    lines += ["", f"One {args.config}-size denoise step ({step['weights_mb']:.0f} MB), floor {step['floor_ms']:.2f} ms",
              "", "| kernel | median ms | p90 ms | x floor | FC ms (profiler) | max abs diff vs torch |",
              "|---|---|---|---|---|---|"]
    for k in ("mlas", "onednn"):
        lines.append(f"| {k} | {step['median_ms'][k]:.2f} | {step['p90_ms'][k]:.2f} | "
                     f"{step['median_ms'][k] / step['floor_ms']:.2f} | {step['fully_connected'][k]['ms']:.2f} | "
                     f"{step['max_abs_diff_vs_torch'][k]:.1e} |")
    with atomic_path(out / "fc-kernel.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
