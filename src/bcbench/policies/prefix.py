"""Training-time delay conditioning: training-time Real-Time Chunking (Black, Ren, Equi, Levine 2025, "Training-Time
Action Conditioning for Efficient Real-Time Chunking", arXiv 2512.05964), for Diffusion Policy and flow matching.

Inference-time RTC (bcbench.policies.guidance) inpaints the new chunk towards the actions that will execute while it
computes. The training-time form simulates that delay during training instead: each training chunk draws a delay d
(here uniformly from the config's `delay_train` = (lo, hi)), its d actions from the current step on are given
clean, in place of noise, and they are left out of the loss; the network learns to continue a given prefix. At
inference the prefix is the executing chunk's actions for those d steps (`--strategy prefix`), re-imposed at every
denoising step. No guidance, no backward pass: the call costs what naive's does (one mask channel more in the first
convolution).

The paper gives each action token its own flow time (1, the data, on the prefix) in a transformer. bcbench's 1-D
U-Net takes one time for the whole chunk, so a conditioned network reads one channel more: a 0/1 mask, 1 where the
action is given clean; flow's state there is the clean action (its time 1, the data), Diffusion Policy's the clean
action as at timestep 0. A network trained without the feature (`delay_train` = (0, 0)) has no mask channel: it is
today's network, parameter for parameter.

Which indices: a chunk starts at the oldest observation, so the current step is index chunk_start = obs_horizon - 1
(bcbench.policies.learned). The d actions the delay executes are indices chunk_start .. chunk_start + d - 1; the
past ones before chunk_start stay generated (they never execute). So d = 0 gives no prefix, and the strategy at
d = 0 (sync, or the first chunk of an episode) samples exactly as the plain sampler of the same weights.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from bcbench.errors import BCBenchError


@dataclass
class Prefix:
    """Actions given clean: `actions` (B, Tp, A) normalised (read where `mask` is 1), `mask` (B, Tp) 0/1 float."""

    actions: torch.Tensor
    mask: torch.Tensor

    def impose(self, x: torch.Tensor) -> torch.Tensor:
        """x (B, Tp, A) with the clean actions at the masked positions."""
        return torch.where(self.mask[..., None] > 0, self.actions.to(x.dtype), x)

    def network_input(self, x: torch.Tensor) -> torch.Tensor:
        """What a conditioned U-Net reads: [x with the prefix imposed ; mask] (B, Tp, 3)."""
        return torch.cat([self.impose(x), self.mask[..., None].to(x.dtype)], dim=-1)

    def repeat(self, n: int) -> Prefix:
        """The same prefix for n samples of every row (rows repeated in place, as BID's candidates)."""
        return Prefix(self.actions.repeat_interleave(n, 0), self.mask.repeat_interleave(n, 0))


def check_delay_range(delay_train: tuple[int, ...], obs_horizon: int, pred_horizon: int) -> tuple[int, int]:
    """(lo, hi) validated: 0 <= lo <= hi, and the chunk keeps at least one generated action after the prefix."""
    if len(delay_train) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in delay_train):
        raise BCBenchError(f"delay_train must be two whole numbers (lo, hi), got {delay_train!r}")
    lo, hi = delay_train
    top = pred_horizon - obs_horizon  # chunk_start + hi <= pred_horizon - 1
    if not 0 <= lo <= hi <= top:
        raise BCBenchError(f"delay_train (lo, hi) must have 0 <= lo <= hi <= pred_horizon - obs_horizon = {top}, "
                           f"got ({lo}, {hi})")
    return lo, hi


def delay_mask(delays: torch.Tensor, chunk_start: int, pred_horizon: int) -> torch.Tensor:
    """(B,) delays -> (B, Tp) mask, 1 on indices chunk_start .. chunk_start + d - 1."""
    k = torch.arange(pred_horizon, device=delays.device)[None]  # (1, Tp)
    return ((k >= chunk_start) & (k < chunk_start + delays[:, None])).float()


def train_prefix(policy: Any, batch: dict[str, Any], delay_train: tuple[int, int], chunk_start: int) -> Prefix:
    """The training prefix of a batch: d ~ uniform{lo..hi} per row, drawn like the policy's other per-row
    randomness (BCPolicy.train_draw: shard-invariant, resumed exactly), the batch's own actions as the clean values."""
    lo, hi = delay_train
    action = batch["action"]  # (B, Tp, A)
    u = policy.train_draw(batch, torch.rand)  # (B,) in [0, 1)
    delays = (lo + (u * (hi - lo + 1)).long()).clamp_(max=hi)
    return Prefix(action, delay_mask(delays, chunk_start, action.shape[1]))


def masked_mse(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean squared error over the positions not given clean: pred, target (B, Tp, A), mask (B, Tp) 1 = left out."""
    free = (1.0 - mask)[..., None]  # (B, Tp, 1)
    return ((pred - target) ** 2 * free).sum() / (free.sum() * pred.shape[-1]).clamp(min=1.0)
