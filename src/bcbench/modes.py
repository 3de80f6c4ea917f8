"""Inference mode names (torch-free): what `--backend/--precision/--reference` select.

    reference      torch fp32; Diffusion Policy and flow call the plain U-Net at every step (the paper's way)
    fast           torch fp32; FiLM split (bcbench.policies.denoiser): exact, the default of eval and study
    openvino-fp32  the graphs exported to OpenVINO and compiled for this CPU at f32: exact
    openvino-bf16  the same with a bf16 inference-precision hint: approximate
    openvino-int8  NNCF post-training quantisation: approximate

How each runs is bcbench.evaluation.backends; the analysis reads these names only.
"""

from __future__ import annotations

from bcbench.errors import BCBenchError

MODES = ("reference", "fast", "openvino-fp32", "openvino-bf16", "openvino-int8")
EXACT_MODES = ("reference", "fast", "openvino-fp32")
PRECISIONS = ("fp32", "bf16", "int8")
BACKENDS = ("torch", "openvino")


def mode_name(backend: str, precision: str = "fp32", reference: bool = False) -> str:
    """The mode of --backend/--precision(/--reference) arguments, checked."""
    if backend == "torch":
        if precision != "fp32":
            raise BCBenchError(f"--precision {precision} needs --backend openvino (torch runs fp32)")
        return "reference" if reference else "fast"
    if backend != "openvino" or precision not in PRECISIONS:
        raise BCBenchError(f"unknown backend/precision '{backend}/{precision}' (torch, or openvino with "
                           f"{', '.join(PRECISIONS)})")
    if reference:
        raise BCBenchError("--reference is the torch reference form; it does not combine with --backend openvino")
    return f"openvino-{precision}"
