"""Behavior Chunking Transformer (BCT): the study's own transformer policy (23,952,736 parameters there).

ResNet-18 (BatchNorm) features of each frame, concatenated with the normalised agent position, become
one token per observation; learned query tokens, one per future step, join them in a bidirectional
transformer encoder (Vaswani et al., 2017) and are read out as the whole 16x2 chunk at once, as in ACT's
action chunking (Zhao et al., RSS 2023). L1 or MSE loss.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

from bcbench.errors import BCBenchError
from bcbench.policies.config import OptimConfig, PolicyConfig, cpu_profile, pick_preset
from bcbench.policies.encoders import RESNET18_LAYERS, FrameFeatures
from bcbench.policies.learned import BCPolicy
from bcbench.tasks import Task


@dataclass
class BCTConfig(PolicyConfig):
    encoder_width: int = 64
    """ResNet-18 base width (64 = the real ResNet-18)"""
    encoder_layers: tuple[int, ...] = RESNET18_LAYERS
    """basic blocks per ResNet stage"""
    d_model: int = 512
    """transformer width"""
    n_heads: int = 8
    """attention heads"""
    n_layers: int = 4
    """encoder layers"""
    ffn_dim: int = 2048
    """feed-forward width"""
    dropout: float = 0.1
    """dropout in the transformer"""
    loss: str = "l1"
    """l1 (ACT's choice) or mse"""
    optim: OptimConfig = field(default_factory=lambda: OptimConfig(
        optimizer="adamw", lr=1e-4, weight_decay=1e-4, schedule="cosine", warmup_steps=500, epochs=100,
        batch_size=64))

    def __post_init__(self) -> None:
        super().__post_init__()
        self.encoder_layers = tuple(self.encoder_layers)
        if self.d_model % self.n_heads:
            raise BCBenchError(f"d_model {self.d_model} must divide by n_heads {self.n_heads}")
        if self.loss not in ("l1", "mse") or not 0 <= self.dropout < 1:
            raise BCBenchError("loss must be l1 or mse and dropout in [0, 1)")

    @classmethod
    def preset(cls, name: str) -> BCTConfig:
        return pick_preset("bct", name, {
            "quick": lambda: cls(  # 1/4-width encoder, a small transformer: 15 minutes on 2 cores
                encoder_width=16, d_model=128, n_heads=4, n_layers=2, ffn_dim=512,
                optim=OptimConfig(optimizer="adamw", lr=1e-3, weight_decay=1e-4, schedule="cosine",
                                  warmup_steps=100, epochs=4, batch_size=64, checkpoint_every=200)),
            # batch 64 (4x the updates of 256 at the same 30 epochs): chosen on validation seeds by
            # results/cpu-explore-small (0.562 vs 0.468 over 50 episodes, paired +0.093 [-0.012, +0.200])
            "cpu": lambda: cpu_profile(cls.preset("quick"), epochs=30, batch_size=64),
            "paper": cls,
        })


class BCTPolicy(BCPolicy):
    name = "bct"
    graphs = ("forward",)  # the whole policy is one graph: (image, agent_pos) -> chunk

    def __init__(self, config: BCTConfig, task: Task | None = None) -> None:
        super().__init__()
        self.config = c = config
        self.use_task(task)
        self.encoder = FrameFeatures("batch", c.encoder_width, c.encoder_layers)
        self.obs_proj = nn.Linear(self.encoder.out_dim + self.state_dim, c.d_model)
        self.obs_pos = nn.Parameter(torch.zeros(1, c.obs_horizon, c.d_model))
        self.queries = nn.Parameter(torch.zeros(1, c.pred_horizon, c.d_model))  # one per future step
        nn.init.normal_(self.obs_pos, std=0.02)
        nn.init.normal_(self.queries, std=0.02)
        layer = nn.TransformerEncoderLayer(c.d_model, c.n_heads, c.ffn_dim, c.dropout, batch_first=True,
                                           norm_first=True)
        self.transformer = nn.TransformerEncoder(layer, c.n_layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(c.d_model)
        self.action_head = nn.Linear(c.d_model, self.action_dim)

    def forward(self, image: torch.Tensor, agent_pos: torch.Tensor) -> torch.Tensor:
        obs = torch.cat([self.encoder(image), agent_pos], dim=-1)  # (B, To, F + S)
        tokens = self.obs_proj(obs) + self.obs_pos  # (B, To, D)
        queries = self.queries.expand(tokens.shape[0], -1, -1)  # (B, Tp, D)
        # No mask: every query attends to every observation and to the other queries, so the chunk is
        # predicted jointly (temporally consistent), not step by step.
        x = self.transformer(torch.cat([tokens, queries], dim=1))  # (B, To + Tp, D)
        return self.action_head(self.norm(x[:, tokens.shape[1]:]))  # (B, Tp, A)

    def compute_loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        pred = self(batch["image"], batch["agent_pos"])
        loss = F.l1_loss if self.config.loss == "l1" else F.mse_loss
        return loss(pred, batch["action"])

    def predict_action_chunk(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.call_graph("forward", obs["image"], obs["agent_pos"])
