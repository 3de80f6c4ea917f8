"""Inference mode names (torch-free): what `--backend/--precision/--reference` select.

    reference      torch fp32; Diffusion Policy and flow call the plain U-Net at every step (the paper's way)
    fast           torch fp32; FiLM split (bcbench.policies.denoiser): exact, the default of eval and study
    openvino-fp32  the graphs exported to OpenVINO and compiled for this CPU at f32: exact
    openvino-bf16  the same with a bf16 inference-precision hint: approximate
    openvino-int8  NNCF post-training quantisation (int8 weights and activations): approximate
    openvino-int8w NNCF weight compression (int8 weights, float activations; no calibration): approximate
    onnxruntime-fp32  the graphs exported to ONNX and run by ONNX Runtime's CPU provider: exact
    onnxruntime-int8  those graphs, their matrix products quantised by ONNX Runtime (dynamic int8): approximate

How each runs is bcbench.evaluation.backends; the analysis reads these names only.
"""

from __future__ import annotations

from bcbench.errors import BCBenchError

MODES = ("reference", "fast", "openvino-fp32", "openvino-bf16", "openvino-int8", "openvino-int8w",
         "onnxruntime-fp32", "onnxruntime-int8")
EXACT_MODES = ("reference", "fast", "openvino-fp32", "onnxruntime-fp32")
TORCH_MODES = ("reference", "fast", "auto")  # what runs on a GPU too (auto resolves to torch there)
PRECISIONS = ("fp32", "bf16", "int8", "int8w")  # OpenVINO's; ONNX Runtime: fp32, int8
BACKENDS = ("torch", "openvino", "onnxruntime", "auto")
BACKEND_MODES = {"torch": "fast", "openvino": "openvino-fp32", "onnxruntime": "onnxruntime-fp32", "auto": "auto"}
AUTO = "auto"  # the fastest exact mode on this machine for this checkpoint, measured (bcbench.evaluation.auto)


def mode_name(backend: str, precision: str = "fp32", reference: bool = False) -> str:
    """The mode of --backend/--precision(/--reference) arguments, checked. A mode's own name (`latency --backend`
    takes those: fast, openvino-bf16, ...) is accepted as the backend too, alone."""
    if backend in MODES:
        if precision != "fp32" or reference:
            raise BCBenchError(f"--backend {backend} names a mode already: no --precision or --reference with it")
        return backend
    if backend == AUTO:
        if precision != "fp32" or reference:
            raise BCBenchError("--backend auto picks among the exact (fp32) modes: no --precision or --reference")
        return AUTO
    if backend == "torch":
        if precision != "fp32":
            raise BCBenchError(f"--precision {precision} needs --backend openvino (torch runs fp32)")
        return "reference" if reference else "fast"
    if reference:
        raise BCBenchError(f"--reference is the torch reference form; it does not combine with --backend {backend}")
    if backend == "onnxruntime" and precision in ("fp32", "int8"):
        return f"onnxruntime-{precision}"
    if backend != "openvino" or precision not in PRECISIONS:
        raise BCBenchError(f"unknown backend/precision '{backend}/{precision}' (torch, onnxruntime with fp32 or "
                           f"int8, or openvino with {', '.join(PRECISIONS)})")
    return f"openvino-{precision}"
