"""The policy registry: name -> (Config class, Policy class).

Every config class has `preset(name)` for `quick` (trains on a 2-core CPU) and `paper` (the study's
architecture and hyper-parameters). Learned policies are `BCPolicy` modules (trained with `bcbench
train`); baselines are ready-to-run `ChunkPolicy` objects.
"""

from __future__ import annotations

from typing import Any

from bcbench.errors import BCBenchError
from bcbench.policies.baselines import BaselineConfig, RandomPolicy, ScriptedPolicy
from bcbench.policies.bct import BCTConfig, BCTPolicy
from bcbench.policies.bet import BeTConfig, BeTPolicy
from bcbench.policies.cnn_mlp import CNNMLPConfig, CNNMLPPolicy
from bcbench.policies.diffusion import DiffusionConfig, DiffusionPolicy
from bcbench.policies.flow import FlowConfig, FlowPolicy
from bcbench.policies.learned import BCPolicy
from bcbench.policies.resnet50_cnn import ResNet50Config, ResNet50Policy

REGISTRY: dict[str, tuple[type, type]] = {
    "random": (BaselineConfig, RandomPolicy),
    "scripted": (BaselineConfig, ScriptedPolicy),
    "cnn_mlp": (CNNMLPConfig, CNNMLPPolicy),
    "resnet50": (ResNet50Config, ResNet50Policy),
    "bet": (BeTConfig, BeTPolicy),
    "bct": (BCTConfig, BCTPolicy),
    "diffusion": (DiffusionConfig, DiffusionPolicy),
    "flow": (FlowConfig, FlowPolicy),
}

# How each `cpu` preset departs from the recipe of its paper (the report lists these), and why.
CPU_DEVIATIONS: dict[str, str] = {
    "cnn_mlp": "the study's network; Adam 1e-3 (study 1e-2) at batch 256 (study 64), 20 epochs (study 50) with "
               "reduce-on-plateau; bf16 autocast",
    "resnet50": "the study's topology at 1/8 width with one bottleneck per stage (0.49 M instead of 34.5 M "
                "parameters), random init (study: ImageNet); Adam 1e-3 (study 1e-4), batch 256, 20 epochs "
                "(study 30); bf16 autocast",
    "bet": "a chunked BeT (16-step chunk from the newest token; BeT predicts per step); 1/4-width ResNet-18 with "
           "one block per stage, 3 layers of width 96 (BeT: 4-6 of 72-120), 32 bins; AdamW 1e-3 at batch 256, "
           "30 epochs, cosine; bf16 autocast",
    "bct": "1/4-width ResNet-18 with one block per stage, a 2-layer width-128 transformer (study: 4 of 512); "
           "AdamW 1e-3 at batch 256, 30 epochs, cosine; bf16 autocast",
    "diffusion": "1/4-width ResNet-18/GroupNorm with one block per stage and a 64/128/256 U-Net (5.3 M instead "
                 "of 91.1 M parameters); AdamW 1e-3 (paper 1e-4) at batch 256 (paper 64), 100 warm-up steps "
                 "(paper 500), 60 epochs (paper 100); EMA, crop, cosine schedule as the paper; bf16 autocast",
    "flow": "diffusion's cpu network and recipe exactly (same parameters), flow-matching objective",
}

# The study's parameter counts, for `bcbench params` and the report.
STUDY_PARAMETERS: dict[str, int] = {"cnn_mlp": 1_365_494, "resnet50": 34_527_593, "bct": 23_952_736,
                                    "diffusion": 91_123_778}


def is_learned(name: str) -> bool:
    return name in REGISTRY and issubclass(REGISTRY[name][1], BCPolicy)


def learned_policies() -> list[str]:
    return [n for n in REGISTRY if is_learned(n)]


def make_config(name: str, preset: str = "quick", overrides: dict[str, Any] | None = None) -> Any:
    from bcbench.policies.config import with_overrides

    if name not in REGISTRY:
        raise BCBenchError(f"unknown policy '{name}' (registered: {', '.join(sorted(REGISTRY))})")
    cfg = REGISTRY[name][0].preset(preset)
    return with_overrides(cfg, overrides) if overrides else cfg


def make_policy(name: str, config: str = "quick", **overrides: Any) -> Any:
    """Build a registered policy from a preset with (dotted) field overrides."""
    cfg = make_config(name, config, overrides)
    return REGISTRY[name][1](cfg)
