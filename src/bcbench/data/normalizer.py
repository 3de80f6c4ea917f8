"""Min-max normalisation to [-1, 1] (Diffusion Policy's convention for agent position and action).

Statistics come from the training split only. The normalizer serialises to a plain dict so that it can
travel with every checkpoint as JSON.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bcbench.errors import BCBenchError

_EPS = 1e-6  # a constant dimension maps to 0 instead of dividing by zero


@dataclass
class MinMaxNormalizer:
    """Per-key, per-dimension affine map from [min, max] to [-1, 1]."""

    stats: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    @classmethod
    def fit(cls, data: dict[str, np.ndarray]) -> MinMaxNormalizer:
        stats = {}
        for key, arr in data.items():
            flat = np.asarray(arr, dtype=np.float64).reshape(-1, arr.shape[-1])
            stats[key] = {"min": flat.min(axis=0).astype(np.float32), "max": flat.max(axis=0).astype(np.float32)}
        return cls(stats)

    def _scale_offset(self, key: str) -> tuple[np.ndarray, np.ndarray]:
        if key not in self.stats:
            raise BCBenchError(f"normalizer has no statistics for '{key}' (has: {', '.join(self.stats)})")
        lo, hi = self.stats[key]["min"], self.stats[key]["max"]
        rng = np.maximum(hi - lo, _EPS)
        scale = 2.0 / rng
        offset = -1.0 - lo * scale
        return scale.astype(np.float32), offset.astype(np.float32)

    def normalize(self, key: str, x: Any) -> Any:
        """x -> 2 (x - min) / (max - min) - 1. Works on numpy arrays and torch tensors alike."""
        scale, offset = self._scale_offset(key)
        return x * _like(scale, x) + _like(offset, x)

    def unnormalize(self, key: str, y: Any) -> Any:
        scale, offset = self._scale_offset(key)
        return (y - _like(offset, y)) / _like(scale, y)

    def to_dict(self) -> dict[str, dict[str, list[float]]]:
        return {k: {s: v.tolist() for s, v in d.items()} for k, d in self.stats.items()}

    @classmethod
    def from_dict(cls, d: dict[str, dict[str, list[float]]]) -> MinMaxNormalizer:
        try:
            return cls({k: {s: np.asarray(v, dtype=np.float32) for s, v in st.items()} for k, st in d.items()})
        except (AttributeError, TypeError, ValueError) as exc:
            raise BCBenchError(f"malformed normalizer statistics: {exc}") from None


def _like(a: np.ndarray, ref: Any) -> Any:
    """`a` as the same array type (and device) as `ref`."""
    if isinstance(ref, np.ndarray | np.generic | float | int):
        return a
    import torch  # the data stage serves numpy callers too: torch only when a tensor is passed

    if isinstance(ref, torch.Tensor):
        return torch.as_tensor(a, dtype=ref.dtype, device=ref.device)
    return a
