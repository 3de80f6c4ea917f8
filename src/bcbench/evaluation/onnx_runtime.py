"""The ONNX Runtime backend (`onnxruntime-fp32`, exact): the policy's inference graphs exported to ONNX and run by
ONNX Runtime's CPU execution provider, through the same `call_graph` seam as OpenVINO.

Exported with torch's TorchScript-based ONNX exporter (opset 17) with a dynamic batch axis; graph optimisations at
ORT_ENABLE_ALL, one session per graph, intra-op threads as torch's. Exports are cached like OpenVINO's (keyed by
checkpoint, weights and the onnxruntime version; written atomically). On the 2-core AMD EPYC Zen 3 (AVX2 only) a
plain export of paper-size Diffusion Policy ran faster than OpenVINO fp32 (issue 28); which wins depends on the CPU,
so measure with `bcbench latency --mode onnxruntime-fp32 --mode openvino-fp32`.

`onnxruntime-int8` (approximate) quantises the exported graphs' matrix products (MatMul, Gemm: every layer of
Diffusion Policy's U-Net in its channels-last export form, the transformers' projections, the MLP heads) with ONNX
Runtime's dynamic quantisation: int8 weights per output channel, activations quantised per call from their own
range, so no calibration data is needed. Convolutions of the image encoders stay fp32 (ONNX Runtime's integer
convolution is slower than its fp32 one on CPUs). On a CPU without an int8 dot-product instruction (VNNI) the
u8 x s8 products are summed in 16 bits, which can saturate: there the weights take 7 bits (`reduce_range`, as
ONNX Runtime's documentation advises), and the deployment record says which was used.
"""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bcbench.errors import BCBenchError
from bcbench.policies.learned import BCPolicy, GraphModule
from bcbench.utils.io import atomic_dir
from bcbench.utils.system import cpu_has_vnni

OPSET = 17


def _ort() -> Any:
    try:
        import onnxruntime  # optional at run time: the torch modes work without it
    except Exception as e:
        raise BCBenchError(f"the ONNX Runtime backend needs the onnxruntime package (make install): {e}") from e
    return onnxruntime


def ort_version() -> str:
    return str(_ort().__version__)


def export_onnx(model: BCPolicy, out_dir: Path) -> Path:
    """Write the policy's graphs as ONNX (`NAME.onnx` each, any batch) into `out_dir`, atomically."""
    model = model.eval()
    fastpath = torch.backends.mha.get_fastpath_enabled()
    torch.backends.mha.set_fastpath_enabled(False)  # attention's fused fast path has no ONNX form: the plain ops
    try:
        with atomic_dir(out_dir, force=True) as staged:
            staged.mkdir()
            for name, example in model.graph_inputs(1).items():
                _export_graph(model, name, example, staged / f"{name}.onnx")
    finally:
        torch.backends.mha.set_fastpath_enabled(fastpath)
    return out_dir


def _export_graph(model: BCPolicy, name: str, example: tuple[torch.Tensor, ...], path: Path) -> None:
    inputs = [f"in{i}" for i in range(len(example))]
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer notes on shape checks that are constant for a policy
        torch.onnx.export(GraphModule(model, name).eval(), tuple(example), str(path), input_names=inputs,
                          dynamic_axes={n: {0: "batch"} for n in inputs}, opset_version=OPSET, dynamo=False)


class _Session:
    """An ONNX Runtime session called like the torch method: torch tensors in, torch tensors out."""

    def __init__(self, path: Path, threads: int) -> None:
        ort = _ort()
        opts = ort.SessionOptions()
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.intra_op_num_threads, opts.inter_op_num_threads = threads, 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        # no spin-waiting after a run: a policy has several sessions (encoder, denoiser), each with its own pool,
        # and an idle pool spinning on a 2-core CPU takes a core from the next session
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        # the bytes, not the path: an export to a temporary folder is deleted once the session exists
        self.session = ort.InferenceSession(path.read_bytes(), opts, providers=["CPUExecutionProvider"])
        self.inputs = [i.name for i in self.session.get_inputs()]
        self.n_out = len(self.session.get_outputs())

    def __call__(self, *args: torch.Tensor) -> Any:
        feed = {n: np.ascontiguousarray(a.detach().cpu().numpy()) for n, a in zip(self.inputs, args, strict=True)}
        outs = [torch.from_numpy(o) for o in self.session.run(None, feed)]
        return outs[0] if self.n_out == 1 else tuple(outs)


def reduce_range() -> bool:
    """7-bit weights for int8 where the CPU has no VNNI (its 16-bit sums of u8 x s8 pairs can saturate)."""
    return not cpu_has_vnni()


def quantize_int8(model: BCPolicy, out_dir: Path) -> Path:
    """Export the policy's graphs and quantise their matrix products to int8 (dynamic), into `out_dir` atomically."""
    from onnxruntime.quantization import QuantType, quantize_dynamic  # only for int8

    with tempfile.TemporaryDirectory(prefix="bcbench-ort-fp32-") as src, atomic_dir(out_dir, force=True) as staged:
        fp32 = export_onnx(model, Path(src) / "graphs")
        staged.mkdir()
        for name in model.graphs:
            quantize_dynamic(fp32 / f"{name}.onnx", staged / f"{name}.onnx", per_channel=True,
                             reduce_range=reduce_range(), weight_type=QuantType.QInt8,
                             op_types_to_quantize=["MatMul", "Gemm"])
    return out_dir


def deploy_onnxruntime(model: BCPolicy, export_dir: Path | None = None, threads: int | None = None,
                       precision: str = "fp32") -> None:
    """Run the policy's graphs in ONNX Runtime (`model.deployed`) at fp32 or int8; exports cached in export_dir."""
    if precision not in ("fp32", "int8"):
        raise BCBenchError(f"ONNX Runtime runs fp32 or int8, not {precision}")
    if export_dir is None:  # nothing to cache it in (an untrained policy): export, load, delete
        with tempfile.TemporaryDirectory(prefix="bcbench-ort-") as tmp:
            deploy_onnxruntime(model, Path(tmp) / "graphs", threads, precision)
        model.deployment["export"] = None
        return
    if not all((export_dir / f"{n}.onnx").exists() for n in model.graphs):
        (quantize_int8 if precision == "int8" else export_onnx)(model, export_dir)
    n = threads or torch.get_num_threads()
    model.deployed = {name: _Session(export_dir / f"{name}.onnx", n) for name in model.graphs}
    model.deployment = {"backend": "onnxruntime", "precision": precision, "onnxruntime": ort_version(),
                        "opset": OPSET, "threads": n, "export": str(export_dir),
                        **({"int8": "dynamic, per-channel weights" + (", 7-bit (no VNNI)" if reduce_range() else "")}
                           if precision == "int8" else {})}
