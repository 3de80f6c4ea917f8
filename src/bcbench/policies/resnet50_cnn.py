"""ResNet-50 CNN: the study's 57-layer convolutional policy (34,527,593 parameters in the study).

One 3-D convolution fuses the frames, one 2-D convolution maps them back to 3 channels so that the 49
layers of ResNet-50 (He et al., CVPR 2016; optionally ImageNet-initialised from a torchvision file) see an
image-like input, four more convolutions shrink the features, two fully connected layers give the 16x2
chunk. BatchNorm and ReLU; MSE loss; Adam at 1e-4 with reduce-on-plateau, 30 epochs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from bcbench.errors import BCBenchError
from bcbench.policies.config import OptimConfig, PolicyConfig, cpu_profile, pick_preset
from bcbench.policies.encoders import RESNET50_LAYERS, load_pretrained, resnet50
from bcbench.policies.regressor import ChunkRegressor, TimeMerge, conv_bn_relu
from bcbench.tasks import Task


@dataclass
class ResNet50Config(PolicyConfig):
    merge_channels: int = 16
    """channels of the 3-D convolution that fuses the frames"""
    width: int = 64
    """ResNet base width (64 = ResNet-50)"""
    layers: tuple[int, ...] = RESNET50_LAYERS
    """bottleneck blocks per stage ((3, 4, 6, 3) = ResNet-50)"""
    head_channels: tuple[int, ...] = (512, 512, 256, 128)
    """output channels of the four convolutions after the ResNet"""
    hidden: int = 5157
    """width of the first fully connected layer (lands on the study's parameter count)"""
    use_agent_pos: bool = True
    """concatenate the agent positions before the fully connected layers"""
    pretrained: str | None = None
    """torchvision-format ImageNet ResNet-50 weights to start from (a local file; never downloaded)"""
    optim: OptimConfig = field(default_factory=lambda: OptimConfig(
        optimizer="adam", lr=1e-4, schedule="plateau", epochs=30, batch_size=64))

    def __post_init__(self) -> None:
        super().__post_init__()
        self.layers, self.head_channels = tuple(self.layers), tuple(self.head_channels)
        if len(self.head_channels) != 4 or len(self.layers) != 4:
            raise BCBenchError("resnet50 needs 4 stages in layers and 4 head_channels")
        if min(self.head_channels + self.layers) < 1 or self.width < 1 or self.hidden < 1:
            raise BCBenchError("resnet50 sizes must be positive")

    @classmethod
    def preset(cls, name: str) -> ResNet50Config:
        return pick_preset("resnet50", name, {
            "quick": lambda: cls(  # same topology at 1/8 width, one block per stage: trains in 15 min on 2 cores
                width=8, layers=(1, 1, 1, 1), head_channels=(128, 128, 64, 32), hidden=256,
                optim=OptimConfig(optimizer="adam", lr=1e-3, schedule="plateau", epochs=4, batch_size=64,
                                  plateau_patience=1, checkpoint_every=200)),
            # batch 64 (4x the updates of 256 at the same 20 epochs): chosen on validation seeds by
            # results/cpu-explore-small (0.489 vs 0.361 over 50 episodes, paired +0.128 [+0.022, +0.232])
            "cpu": lambda: cpu_profile(cls.preset("quick"), epochs=20, batch_size=64),
            "paper": cls,
        })


class ResNet50Policy(ChunkRegressor):
    name = "resnet50"

    def __init__(self, config: ResNet50Config, task: Task | None = None) -> None:
        super().__init__()
        self.config = config
        self.use_task(task)
        self.merge = TimeMerge(config.obs_horizon, config.merge_channels)
        self.to_rgb = nn.Sequential(*conv_bn_relu(config.merge_channels, 3, 3))
        self.backbone = resnet50("batch", config.width, config.layers)
        if config.pretrained:
            load_pretrained(self.backbone, config.pretrained)
        h = config.head_channels
        self.reduce = nn.Sequential(
            *conv_bn_relu(self.backbone.out_channels, h[0], 1), *conv_bn_relu(h[0], h[1], 3),
            *conv_bn_relu(h[1], h[2], 3), *conv_bn_relu(h[2], h[3], 3),
        )
        side = config.image_size // 32 if config.image_size % 32 == 0 else -(-config.image_size // 32)
        n_in = h[3] * side * side + (self.state_dim * config.obs_horizon if config.use_agent_pos else 0)
        self.fc1 = nn.Linear(n_in, config.hidden)
        self.fc2 = nn.Linear(config.hidden, config.pred_horizon * self.action_dim)

    def forward(self, image: torch.Tensor, agent_pos: torch.Tensor) -> torch.Tensor:
        x = self.backbone(self.to_rgb(self.merge(image)))  # (B, 2048, 3, 3) at paper size
        return self.head(self.reduce(x), agent_pos)  # (B, Tp, A)
