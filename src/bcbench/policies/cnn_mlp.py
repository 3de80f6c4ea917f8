"""CNN-MLP: the study's 8-layer convolutional baseline (1,365,494 parameters in the study).

One 3-D convolution over the stacked frames, five stride-2 2-D convolutions (no pooling) widening to 256
channels with BatchNorm and ReLU, then two fully connected layers to the 16x2 chunk. MSE loss, Adam at
1e-2 with reduce-on-plateau, no dropout, no weight decay. Agent positions join before the fully
connected layers (+4 inputs; the study fed images only).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import torch
from torch import nn

from bcbench.errors import BCBenchError
from bcbench.policies.config import OptimConfig, PolicyConfig, cpu_profile, pick_preset
from bcbench.policies.regressor import ChunkRegressor, TimeMerge, conv_bn_relu
from bcbench.tasks import Task


@dataclass
class CNNMLPConfig(PolicyConfig):
    channels: tuple[int, ...] = (16, 32, 64, 128, 256, 256)
    """output channels of the 3-D convolution, then of each of the five stride-2 convolutions"""
    hidden: int = 163
    """width of the first fully connected layer (163 lands on the study's parameter count)"""
    use_agent_pos: bool = True
    """concatenate the agent positions before the fully connected layers"""
    optim: OptimConfig = field(default_factory=lambda: OptimConfig(
        optimizer="adam", lr=1e-2, schedule="plateau", epochs=50, batch_size=64))

    def __post_init__(self) -> None:
        super().__post_init__()
        self.channels = tuple(self.channels)
        if len(self.channels) != 6 or min(self.channels) < 1 or self.hidden < 1:
            raise BCBenchError("cnn_mlp needs 6 positive channel counts (3-D conv + five 2-D convs) and hidden >= 1")

    @classmethod
    def preset(cls, name: str) -> CNNMLPConfig:
        return pick_preset("cnn_mlp", name, {
            "quick": lambda: cls(  # same network (it is small); 4 epochs, about 15 minutes on 2 cores
                optim=OptimConfig(optimizer="adam", lr=1e-3, schedule="plateau", epochs=4, batch_size=64,
                                  plateau_patience=1, checkpoint_every=200)),
            # batch 64 (the study's; 4x the updates of 256 at the same 20 epochs): a tie on validation seeds in
            # results/cpu-explore-small (0.323 vs 0.323 over 50 episodes, paired +0.000 [-0.075, +0.073]), taken
            # for the study's batch and the recipe BCT and ResNet-50 chose there, at the same cost per sample
            "cpu": lambda: cpu_profile(cls.preset("quick"), epochs=20, batch_size=64),
            "paper": cls,
        })


class CNNMLPPolicy(ChunkRegressor):
    name = "cnn_mlp"

    def __init__(self, config: CNNMLPConfig, task: Task | None = None) -> None:
        super().__init__()
        self.config = config
        self.use_task(task)
        c = config.channels
        self.merge = TimeMerge(config.obs_horizon, c[0])
        layers: list[nn.Module] = []
        for cin, cout in itertools.pairwise(c):
            layers += conv_bn_relu(cin, cout, 3, stride=2)  # 96 -> 48 -> 24 -> 12 -> 6 -> 3
        self.convs = nn.Sequential(*layers)
        side = config.image_size
        for _ in range(5):
            side = (side + 1) // 2
        n_in = c[-1] * side * side + (self.state_dim * config.obs_horizon if config.use_agent_pos else 0)
        self.fc1 = nn.Linear(n_in, config.hidden)
        self.fc2 = nn.Linear(config.hidden, config.pred_horizon * self.action_dim)

    def forward(self, image: torch.Tensor, agent_pos: torch.Tensor) -> torch.Tensor:
        return self.head(self.convs(self.merge(image)), agent_pos)  # (B, Tp, A)
