"""The policy registry: name -> (Config class, Policy class).

Every config class has `preset(name)` for `quick` (trains on a 2-core CPU) and `paper` (the study's
architecture and hyper-parameters). Learned policies are `BCPolicy` modules (trained with `bcbench
train`); baselines are ready-to-run `ChunkPolicy` objects.
"""

from __future__ import annotations

from typing import Any

from bcbench.errors import BCBenchError
from bcbench.interface import ChunkPolicy
from bcbench.policies.baselines import BaselineConfig, RandomPolicy, ScriptedPolicy
from bcbench.policies.bct import BCTConfig, BCTPolicy
from bcbench.policies.bet import BeTConfig, BeTPolicy
from bcbench.policies.cnn_mlp import CNNMLPConfig, CNNMLPPolicy
from bcbench.policies.config import with_overrides
from bcbench.policies.correction import CorrectionConfig, CorrectionPolicy
from bcbench.policies.diffusion import DiffusionConfig, DiffusionPolicy
from bcbench.policies.flow import FlowConfig, FlowPolicy
from bcbench.policies.learned import BCPolicy
from bcbench.policies.resnet50_cnn import ResNet50Config, ResNet50Policy
from bcbench.tasks import Task

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

# Trained beside a policy, not policies themselves (not in REGISTRY: nothing lists, times or evaluates them alone):
# `bcbench train --policy correction --set base=RUN_DIR` trains A2C2's head on a frozen base run.
HEADS: dict[str, tuple[type, type]] = {"correction": (CorrectionConfig, CorrectionPolicy)}


def trainable(name: str) -> tuple[type, type]:
    """(Config class, Policy class) of what `bcbench train --policy NAME` trains: a registered policy or a head."""
    if name in REGISTRY:
        return REGISTRY[name]
    if name in HEADS:
        return HEADS[name]
    raise BCBenchError(f"unknown policy '{name}' (registered: {', '.join(sorted(REGISTRY))}; heads: "
                       f"{', '.join(HEADS)})")


def is_learned(name: str) -> bool:
    return name in REGISTRY and issubclass(REGISTRY[name][1], BCPolicy)


def sampler_kinds(name: str) -> tuple[str, ...]:
    """The sampler kinds of a registered policy (generative ones: diffusion, flow), else ()."""
    cls = REGISTRY[name][1]
    return cls.samplers if issubclass(cls, BCPolicy) else ()


def learned_policies() -> list[str]:
    return [n for n in REGISTRY if is_learned(n)]


def make_config(name: str, preset: str = "quick", overrides: dict[str, Any] | None = None) -> Any:
    """The typed config of a registered policy's preset, with (dotted) field overrides."""
    if name not in REGISTRY:
        raise BCBenchError(f"unknown policy '{name}' (registered: {', '.join(sorted(REGISTRY))})")
    cfg = REGISTRY[name][0].preset(preset)
    return with_overrides(cfg, overrides) if overrides else cfg


def make_policy(name: str, preset: str = "quick", task: Task | None = None, **overrides: Any) -> BCPolicy | ChunkPolicy:
    """Build a registered policy from a preset with (dotted) field overrides: a baseline is a ready ChunkPolicy for
    `task` (scripted: Push-T's only, refused elsewhere in one line), a learned policy an untrained BCPolicy network
    in `task`'s shapes (default Push-T; wrap it in a PolicyRunner to run it on raw observations)."""
    cfg = make_config(name, preset, overrides)  # an unknown name or preset: one line naming the choices
    return REGISTRY[name][1](cfg, task)  # a baseline refuses a task it cannot act in
