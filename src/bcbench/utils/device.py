"""The torch device a command runs on (`--device auto|cpu|cuda`)."""

from __future__ import annotations

import torch

from bcbench.errors import BCBenchError


def pick_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise BCBenchError("--device cuda asked for, but torch sees no CUDA device")
    if name not in ("cpu", "cuda"):
        raise BCBenchError(f"--device must be auto, cpu or cuda, got '{name}'")
    return torch.device(name)
