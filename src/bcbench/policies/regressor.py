"""Shared pieces of the direct-regression policies (CNN-MLP, ResNet-50 CNN): MSE on the whole chunk."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from bcbench.policies.learned import BCPolicy


def conv_bn_relu(cin: int, cout: int, kernel: int, stride: int = 1) -> list[nn.Module]:
    return [nn.Conv2d(cin, cout, kernel, stride, kernel // 2), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)]


class TimeMerge(nn.Module):
    """The study's first layer: one 3-D convolution whose temporal kernel spans all To frames.

    (B, To, 3, H, W) -> (B, C, H, W): the frames are fused at the pixel level, so motion is visible to
    every later layer at the cost of one small convolution.
    """

    def __init__(self, obs_horizon: int, out_channels: int) -> None:
        super().__init__()
        self.conv = nn.Conv3d(3, out_channels, kernel_size=(obs_horizon, 3, 3), padding=(0, 1, 1))
        self.bn = nn.BatchNorm2d(out_channels)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        # A 3-D conv whose temporal kernel covers all To frames equals a 2-D conv over the frames stacked
        # as channels; computed that way it is exact and about twice as fast on CPU.
        w = self.conv.weight  # (C, 3, To, 3, 3)
        w2d = w.transpose(1, 2).reshape(w.shape[0], -1, 3, 3)  # (C, To*3, 3, 3), frame-major like the input
        b, t, c, h, wd = image.shape
        # channels-last like every later convolution (trainer and exports store them so): a (B, C, H, W) output
        # here made the next layer copy this, the largest activation, and left its BatchNorm and ReLU (forward
        # and backward) on mixed-format slow paths (1.15x the CNN-MLP's training samples/s at batch 256, 2 AVX2 cores)
        x = image.reshape(b, t * c, h, wd).contiguous(memory_format=torch.channels_last)
        x = F.conv2d(x, w2d.contiguous(memory_format=torch.channels_last), self.conv.bias, padding=1)  # (B, C, H, W)
        return F.relu(self.bn(x))


class ChunkRegressor(BCPolicy):
    """A network that maps the observation window straight to the normalised chunk; MSE loss."""

    graphs = ("forward",)  # the whole policy is one graph: (image, agent_pos) -> chunk

    def forward(self, image: torch.Tensor, agent_pos: torch.Tensor) -> torch.Tensor:  # -> (B, Tp, A)
        raise NotImplementedError

    def compute_loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        pred = self(batch["image"], batch["agent_pos"])
        return F.mse_loss(pred, batch["action"])

    def predict_action_chunk(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.call_graph("forward", obs["image"], obs["agent_pos"])

    def head(self, features: torch.Tensor, agent_pos: torch.Tensor) -> torch.Tensor:
        """Flattened features (+ agent positions) -> two fully connected layers -> (B, Tp, A)."""
        x = features.flatten(1)
        if self.config.use_agent_pos:
            x = torch.cat([x, agent_pos.flatten(1)], dim=1)  # (B, F + To*S)
        return self.fc2(F.relu(self.fc1(x))).view(-1, self.config.pred_horizon, self.action_dim)
