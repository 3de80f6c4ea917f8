"""Why OpenVINO's static int8 moves a trained denoiser's chunks, and whether weight-only int8 does: chunk deviation
against torch fast for variants of the quantisation, one graph at a time.

    .venv/bin/python benchmarks/int8_cause.py RUN_DIR [--sampler euler --steps 10] [--observations 100]
                [--out results/tiers-flow-b-explore/int8-cause]

bcbench's `openvino-int8` mode quantises every graph of a policy with NNCF's post-training quantisation
(`nncf.quantize`: int8 weights and activations, one static scale per activation tensor, calibrated on the graph
inputs recorded while sampling 64 training-split observations: every denoising step's state is in the data).
Each variant below changes one thing:
    static            the mode as shipped (both graphs)
    static-encoder    only the observation encoder graph (`obs_film`) quantised, the U-Net float
    static-unet       only the U-Net (`denoise`) quantised
    static-unet-mm    only the U-Net, and in it only the matrix products' inputs (NNCF ignores the element-wise ops)
    weights           `nncf.compress_weights` (int8 weights, float activations) on both graphs
    openvino-int8w    the same on the U-Net only: the shipped weight-only mode
    openvino-fp32, openvino-bf16, onnxruntime-int8: the other shipped modes, for scale
Deviation: over --observations validation windows (batch 1, the same noise in every variant), the largest and the
mean Euclidean distance in pixels (512 px world) between a chunk's actions and torch fast's. Float ops of the
int8 variants run at bf16 where the CPU computes it natively (as the shipped int8 modes do). No timing here.
Writes int8-cause.json stamped with commit and CPU.
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bcbench.evaluation.backends import dataset_observations, run_data_split, set_mode
from bcbench.policies.checkpoint import configure_runner, load_runner
from bcbench.utils.io import write_json
from bcbench.utils.system import provenance

ELEMENTWISE = ["Add", "Multiply", "Concat", "MVN", "Mish", "Divide"]


def variant_quantizer(variant: str, original: Callable[..., Any], horizon: int) -> Callable[..., Any]:
    """An `nncf.quantize` stand-in for one variant; which graph it is given is read off its inputs' shapes."""
    import nncf

    def takes_chunk(p: Any) -> bool:  # the noisy chunk (B, Tp, 2): only the U-Net takes one (agent_pos: (B, To, 2))
        shape = p.get_partial_shape()
        return shape.rank.is_static and shape.rank.get_length() == 3 and shape[1].is_static \
            and shape[1].get_length() == horizon

    def quantize(model: Any, data: Any, **kw: Any) -> Any:
        is_unet = any(takes_chunk(p) for p in model.get_parameters())
        if ("-unet" in variant and not is_unet) or (variant.endswith("-encoder") and is_unet):
            return model  # this variant leaves this graph float
        if variant.startswith("weights"):
            return nncf.compress_weights(model, mode=nncf.CompressWeightsMode.INT8_ASYM)
        if variant.endswith("-mm"):
            kw["ignored_scope"] = nncf.IgnoredScope(types=ELEMENTWISE, validate=False)
        return original(model, data, **kw)
    return quantize


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run_dir")
    ap.add_argument("--sampler", default="euler")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--observations", type=int, default=100)
    ap.add_argument("--out", type=Path, default=Path("results/tiers-flow-b-explore/int8-cause"))
    args = ap.parse_args()
    import nncf

    runner = load_runner(args.run_dir)
    configure_runner(runner, args.sampler, args.steps)
    model, split = runner.model, run_data_split(args.run_dir)
    obs = dataset_observations(model, "val", args.observations, seed=1, data_split=split)
    calibration = dataset_observations(model, "train", 64, data_split=split)

    def chunks() -> np.ndarray:
        model.reset_noise(0)
        with torch.inference_mode():
            return torch.cat([runner.normalizer.unnormalize("action", model.predict_action_chunk(o).float())
                              for o in obs]).numpy()  # (N, Tp, 2) px

    set_mode(model, "fast")
    base = chunks()
    rows = []
    original = nncf.quantize
    variants = ["openvino-fp32", "openvino-bf16", "onnxruntime-int8", "static", "static-encoder", "static-unet",
                "static-unet-mm", "weights", "openvino-int8w"]
    with tempfile.TemporaryDirectory(prefix="bcbench-int8-") as tmp:
        for v in variants:
            shipped = v.split("-")[0] in ("openvino", "onnxruntime")
            nncf.quantize = original if shipped else variant_quantizer(v, original, model.config.pred_horizon)
            try:
                set_mode(model, v if shipped else "openvino-int8", Path(tmp) / v, calibration)
                deployment = dict(model.deployment)
                dist = np.linalg.norm(chunks() - base, axis=-1)  # (N, Tp) px
            finally:
                nncf.quantize = original
                set_mode(model, "fast")
            rows.append({"variant": v, "max_px": float(dist.max()), "mean_px": float(dist.mean()),
                         "deployment": deployment})
            print(f"{v:18s} max {rows[-1]['max_px']:7.2f} px   mean {rows[-1]['mean_px']:6.2f} px", flush=True)
    write_json(args.out / "int8-cause.json", {"type": "int8-cause", "run_dir": str(args.run_dir),
                                              "policy": runner.describe(), "observations": len(obs),
                                              "rows": rows, **provenance("cpu")})


if __name__ == "__main__":
    main()
