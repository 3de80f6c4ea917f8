"""Tiny configs of every learned policy, small enough to train for a few steps in a test."""

from __future__ import annotations

from pathlib import Path
from typing import Any

TINY: dict[str, dict[str, Any]] = {
    "cnn_mlp": {"channels": [4, 4, 4, 4, 4, 4], "hidden": 8},
    "resnet50": {"merge_channels": 4, "width": 2, "layers": [1, 1, 1, 1], "head_channels": [4, 4, 4, 4], "hidden": 8},
}


def tiny_overrides(name: str, **optim: Any) -> dict[str, Any]:
    """Dotted overrides for `name`'s quick preset: the tiny network plus optimiser settings."""
    base = {"optim.batch_size": 4, "optim.log_every": 1, "optim.checkpoint_every": 2, "optim.epochs": 1,
            "optim.warmup_steps": 0}
    base.update({f"optim.{k}": v for k, v in optim.items()})
    return {**TINY[name], **base}

TINY["diffusion"] = {"encoder_width": 16, "encoder_layers": [1, 1, 1, 1], "down_dims": [8, 16, 32], "n_groups": 4,
                     "step_embed_dim": 8, "sampling_steps": 5, "crop": 88}
TINY["bet"] = {"encoder_width": 16, "encoder_layers": [1, 1, 1, 1], "n_bins": 8, "d_model": 16, "n_heads": 2,
               "n_layers": 2, "dropout": 0.0}
TINY["bct"] = {"encoder_width": 16, "encoder_layers": [1, 1, 1, 1], "d_model": 16, "n_heads": 2, "n_layers": 2,
               "ffn_dim": 32, "dropout": 0.0}
TINY["flow"] = {k: v for k, v in TINY["diffusion"].items() if k != "sampling_steps"} | {"sampling_steps": 3}


def checkpoint_weights(run_dir: Path) -> dict[str, Any]:
    """The raw (not EMA) weights of a run's newest checkpoint, name -> tensor."""
    from safetensors.torch import load_file

    from bcbench.policies.checkpoint import latest_checkpoint

    return load_file(str(latest_checkpoint(run_dir) / "model.safetensors"))
