"""Tiny configs of every learned policy, small enough to train for a few steps in a test."""

from __future__ import annotations

from typing import Any

TINY: dict[str, dict[str, Any]] = {
    "cnn_mlp": {"channels": [4, 4, 4, 4, 4, 4], "hidden": 8},
    "resnet50": {"merge_channels": 4, "width": 2, "layers": [1, 1, 1, 1], "head_channels": [4, 4, 4, 4], "hidden": 8},
}


def tiny_overrides(name: str, **optim: Any) -> dict[str, Any]:
    """Dotted overrides for `name`'s quick preset: the tiny network plus optimiser settings."""
    base = {"optim.batch_size": 4, "optim.log_every": 1, "optim.checkpoint_every": 2, "optim.epochs": 1}
    base.update({f"optim.{k}": v for k, v in optim.items()})
    return {**TINY[name], **base}
