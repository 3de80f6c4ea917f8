"""The published study's numbers (torch-free): one place for everything bcbench compares itself with.

The study timed one inference step of each policy on an A100 and scored each on 40 test seeds; its parameter
counts come from its networks. The report, the figures, `bcbench params`, the A100 latency profile of
real-time evaluation and the presets' documented departures all read them from here.
"""

from __future__ import annotations

from typing import Any

# Parameters of the study's networks.
STUDY_PARAMETERS: dict[str, int] = {"cnn_mlp": 1_365_494, "resnet50": 34_527_593, "bct": 23_952_736,
                                    "diffusion": 91_123_778}
DIFFUSION_PARAMETERS = {"encoder": 11_176_512, "unet": 79_947_266, "total": 91_123_778}

# 3D Diffusion Policy (Ze et al., RSS 2024), its MetaWorld table: image Diffusion Policy trained on 10 scripted
# demonstrations, mean success per difficulty group (Seo et al.'s grouping). Issue 75's yardstick for bcbench's image
# DP on each MetaWorld task of that group; the groups hold many tasks, so a single task's number can sit far from it.
IMAGE_DP_3DDP: dict[str, float] = {"easy": 0.836, "medium": 0.311, "hard": 0.090, "very hard": 0.266}

# The study's networks at full width (ResNet base width 64) and, for ResNet-50, ImageNet-initialised: a model that
# departs from them is named with its own size wherever it is shown (`sized_label`), since a reader of "ResNet-50 CNN"
# assumes the study's 34.5 M ImageNet network. Flow matching runs Diffusion Policy's network; BeT's study size is
# unknown (it reports none), so its own size is always shown.
FULL_WIDTH = 64
_SIZE_REFERENCE = {"cnn_mlp": "cnn_mlp", "resnet50": "resnet50", "bct": "bct", "diffusion": "diffusion",
                   "flow": "diffusion", "bet": None}


def sized_label(label: str, policy: str, params: int, config: dict[str, Any] | None) -> str:
    """`label` with the model's size and init where it is not the study's network: "ResNet-50 CNN, 1/8 width (0.49 M,
    random init)"; unchanged for the study's own sizes (within 5% of its count, full width, its init), for policies
    the study has no network for (baselines, a user's policy) and for a record without its full config or parameter
    count (nothing to say)."""
    if policy not in _SIZE_REFERENCE or "pred_horizon" not in (config or {}) or not params:
        return label
    cfg = config or {}
    study = STUDY_PARAMETERS.get(_SIZE_REFERENCE[policy] or "")
    width = cfg.get("width") if policy == "resnet50" else cfg.get("encoder_width")
    narrow = f", 1/{FULL_WIDTH // width} width" if width and width < FULL_WIDTH and FULL_WIDTH % width == 0 else (
        f", {width}/{FULL_WIDTH} width" if width and width < FULL_WIDTH else "")
    init = ", random init" if policy == "resnet50" and not cfg.get("pretrained") else ""
    same_size = bool(study and abs(params - study) <= 0.05 * study)
    if same_size and not narrow and not init:
        return label
    return f"{label}{narrow} ({params / 1e6:.2f} M{init})"


# The study's A100 inference times (ms per call): Diffusion Policy at 10 and 100 DDPM steps, the others.
A100_DP_MS = {10: 116.5, 100: 1109.4}
A100_MS = {"cnn_mlp": 2.2, "resnet50": 13.0, "bct": 12.0}

# The study's own results (A100), shown beside ours.
STUDY_REFERENCE: dict[str, dict[str, Any]] = {
    "cnn_mlp": {"params": STUDY_PARAMETERS["cnn_mlp"], "score": 0.29, "gt05": 0.25, "gt09": 0.025,
                "latency_ms": A100_MS["cnn_mlp"]},
    "resnet50": {"params": STUDY_PARAMETERS["resnet50"], "score": 0.41, "gt05": 0.40, "gt09": 0.325,
                 "latency_ms": A100_MS["resnet50"]},
    "bct": {"params": STUDY_PARAMETERS["bct"], "score": 0.32, "gt05": 0.30, "gt09": 0.10,
            "latency_ms": A100_MS["bct"]},
    "bet": {"params": None, "score": 0.0, "gt05": 0.0, "gt09": 0.0, "latency_ms": None},
    "diffusion:ddpm10": {"params": STUDY_PARAMETERS["diffusion"], "score": None, "latency_ms": A100_DP_MS[10]},
    "diffusion:ddpm100": {"params": STUDY_PARAMETERS["diffusion"], "score": None, "latency_ms": A100_DP_MS[100]},
}

# How each `cpu` preset's network departs from its paper's (a run records its own copy in run.json). The recipe
# (optimiser, lr, batch, steps, precision) is not here: the report states it from each run's own config, since
# presets' recipes change as explore studies choose them and a text kept beside them went stale once (the DP/flow
# recipe B of results/cpu-explore-dpflow).
CPU_DEVIATIONS: dict[str, str] = {
    "cnn_mlp": "the study's network (study recipe: Adam 1e-2, batch 64, 50 epochs)",
    "resnet50": "the study's topology at 1/8 width with one bottleneck per stage (0.49 M instead of 34.5 M "
                "parameters), random init (study: ImageNet; Adam 1e-4, batch 64, 30 epochs)",
    "bet": "a chunked BeT (16-step chunk from the newest token; BeT predicts per step); 1/4-width ResNet-18 with "
           "one block per stage, 3 layers of width 96 (BeT: 4-6 of 72-120), 32 bins",
    "bct": "1/4-width ResNet-18 with one block per stage, a 2-layer width-128 transformer (study: 4 of 512)",
    "diffusion": "1/4-width ResNet-18/GroupNorm with one block per stage and a 64/128/256 U-Net (5.3 M instead "
                 "of 91.1 M parameters); EMA, crop and cosine betas as the paper (paper recipe: AdamW 1e-4, "
                 "batch 64, 500 warm-up steps)",
    "flow": "diffusion's cpu network exactly (same parameters), flow-matching objective",
}
