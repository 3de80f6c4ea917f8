"""A chunked variant of the Behavior Transformer (BeT; Shafiullah et al., NeurIPS 2022).

BeT as published predicts one action per step from a window of observations; this variant predicts a
16-step chunk of binned actions from the newest token and runs in the same receding-horizon controller
as the other policies (the study does not say which it ran). Everything else follows BeT:

Actions are discretised by k-means over the training split (fitted once, saved with the weights as a
buffer). A minGPT-style causal transformer reads one token per observation (ResNet-18 features of the
frame concatenated with the normalised agent position); from the newest token, the head predicts, for
each of the 16 future steps, logits over the k bins and a continuous offset per bin. Training: focal
loss (gamma 2) on the bin of each target action plus a scaled MSE on that bin's offset. Sampling draws a
bin from the softmax and adds its offset.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from bcbench.data.sequence import SequenceDataset
from bcbench.errors import BCBenchError
from bcbench.policies.config import OptimConfig, PolicyConfig, cpu_profile, pick_preset
from bcbench.policies.encoders import RESNET18_LAYERS, FrameFeatures
from bcbench.policies.learned import BCPolicy
from bcbench.tasks import Task


@dataclass
class BeTConfig(PolicyConfig):
    encoder_width: int = 64
    """ResNet-18 base width (64 = the real ResNet-18)"""
    encoder_layers: tuple[int, ...] = RESNET18_LAYERS
    """basic blocks per ResNet stage"""
    n_bins: int = 64
    """k-means action bins (BeT used 24-64)"""
    d_model: int = 120
    """transformer width (BeT: 72-120)"""
    n_heads: int = 6
    """attention heads"""
    n_layers: int = 6
    """transformer blocks"""
    dropout: float = 0.1
    """dropout in the transformer"""
    focal_gamma: float = 2.0
    """focal-loss focusing parameter"""
    offset_weight: float = 100.0
    """weight of the offset MSE against the bin loss (BeT's 'offset_loss_scale')"""
    optim: OptimConfig = field(default_factory=lambda: OptimConfig(
        optimizer="adamw", lr=1e-4, weight_decay=0.1, betas=(0.9, 0.95), schedule="cosine", warmup_steps=500,
        epochs=100, batch_size=64, grad_clip=1.0))

    def __post_init__(self) -> None:
        super().__post_init__()
        self.encoder_layers = tuple(self.encoder_layers)
        if self.d_model % self.n_heads:
            raise BCBenchError(f"d_model {self.d_model} must divide by n_heads {self.n_heads}")
        if self.n_bins < 2:
            raise BCBenchError(f"n_bins must be >= 2, got {self.n_bins}")

    @classmethod
    def preset(cls, name: str) -> BeTConfig:
        return pick_preset("bet", name, {
            "quick": lambda: cls(
                encoder_width=16, n_bins=32, d_model=96, n_heads=4, n_layers=3,
                optim=OptimConfig(optimizer="adamw", lr=1e-3, weight_decay=0.1, betas=(0.9, 0.95),
                                  schedule="cosine", warmup_steps=100, epochs=4, batch_size=64, grad_clip=1.0,
                                  checkpoint_every=200)),
            # batch 64 (4x the updates of 256 at the same 30 epochs): chosen on validation seeds by
            # results/cpu-explore-small (0.607 vs 0.524 over 50 episodes, paired +0.083 [-0.045, +0.208])
            "cpu": lambda: cpu_profile(cls.preset("quick"), epochs=30, batch_size=64),
            "paper": cls,
        })


def kmeans(x: np.ndarray, k: int, iters: int = 50, seed: int = 0) -> np.ndarray:
    """Lloyd's k-means with k-means++ seeding; returns (k, D) centres."""
    rng = np.random.default_rng(seed)
    x = np.asarray(x, dtype=np.float64)
    if len(x) < k:
        raise BCBenchError(f"k-means needs at least {k} points, got {len(x)}")
    centres = [x[rng.integers(len(x))]]
    d2 = ((x - centres[0]) ** 2).sum(1)
    for _ in range(k - 1):  # k-means++: far points are likelier seeds
        centres.append(x[rng.choice(len(x), p=d2 / d2.sum()) if d2.sum() > 0 else rng.integers(len(x))])
        d2 = np.minimum(d2, ((x - centres[-1]) ** 2).sum(1))
    c = np.stack(centres)
    for _ in range(iters):
        assign = ((x[:, None, :] - c[None]) ** 2).sum(-1).argmin(1)
        new = np.stack([x[assign == j].mean(0) if np.any(assign == j) else c[j] for j in range(k)])
        if np.allclose(new, c):
            break
        c = new
    return c.astype(np.float32)


class Block(nn.Module):
    """minGPT block: pre-LayerNorm causal self-attention and MLP."""

    def __init__(self, d: int, heads: int, dropout: float) -> None:
        super().__init__()
        self.ln1, self.ln2 = nn.LayerNorm(d), nn.LayerNorm(d)
        self.attn = nn.MultiheadAttention(d, heads, dropout=dropout, batch_first=True)
        self.mlp = nn.Sequential(nn.Linear(d, 4 * d), nn.GELU(), nn.Linear(4 * d, d), nn.Dropout(dropout))

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        h = self.ln1(x)
        x = x + self.attn(h, h, h, attn_mask=mask, need_weights=False)[0]
        return x + self.mlp(self.ln2(x))


class BeTPolicy(BCPolicy):
    name = "bet"
    graphs = ("heads",)  # observations -> bin logits and offsets; the bin is drawn in Python

    def __init__(self, config: BeTConfig, task: Task | None = None) -> None:
        super().__init__()
        self.config = c = config
        self.use_task(task)
        self.encoder = FrameFeatures("batch", c.encoder_width, c.encoder_layers)
        self.tok = nn.Linear(self.encoder.out_dim + self.state_dim, c.d_model)
        self.pos = nn.Parameter(torch.zeros(1, c.obs_horizon, c.d_model))
        self.drop = nn.Dropout(c.dropout)
        self.blocks = nn.ModuleList(Block(c.d_model, c.n_heads, c.dropout) for _ in range(c.n_layers))
        self.ln_f = nn.LayerNorm(c.d_model)
        # per step: k logits and k offsets of action_dim values
        self.head = nn.Linear(c.d_model, c.pred_horizon * c.n_bins * (1 + self.action_dim))
        # True above the diagonal = not allowed to attend: token t sees tokens <= t only (causal).
        self.register_buffer("mask", torch.triu(torch.ones(c.obs_horizon, c.obs_horizon, dtype=torch.bool), 1),
                             persistent=False)
        self.register_buffer("centres", torch.zeros(c.n_bins, self.action_dim))  # k-means bins, saved with the weights

    def fit_data(self, train_ds: SequenceDataset) -> None:
        """Fit the k-means bins on the normalised actions of the training split (once, before training)."""
        steps = np.unique(train_ds.indices)
        actions = train_ds.normalizer.normalize("action", train_ds.buffer.action[steps])
        self.centres.copy_(torch.from_numpy(kmeans(actions, self.config.n_bins, seed=self.config.seed)))

    def transformer(self, image: torch.Tensor, agent_pos: torch.Tensor) -> torch.Tensor:
        """(B, To, ...) observations -> per-token outputs (B, To, D), causally masked."""
        x = self.drop(self.tok(torch.cat([self.encoder(image), agent_pos], dim=-1)) + self.pos)
        for block in self.blocks:
            x = block(x, self.mask[: x.shape[1], : x.shape[1]])
        return self.ln_f(x)

    def heads(self, image: torch.Tensor, agent_pos: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The inference graph: observations -> bin logits and offsets (sampling stays in Python)."""
        h = self.transformer(image, agent_pos)[:, -1]  # newest token: (B, D)
        c = self.config
        out = self.head(h).view(-1, c.pred_horizon, c.n_bins, 1 + self.action_dim)
        return out[..., 0], out[..., 1:]  # logits (B, Tp, k), offsets (B, Tp, k, A)

    def optim_groups(self, weight_decay: float) -> list[dict[str, Any]]:
        """minGPT's parameter groups: weight decay on matrices and convolution kernels only, never on biases,
        norm scales or the position embedding."""
        decay, no_decay = [], []
        for name, p in self.named_parameters():
            (decay if p.ndim >= 2 and name != "pos" else no_decay).append(p)
        return [{"params": decay, "weight_decay": weight_decay}, {"params": no_decay, "weight_decay": 0.0}]

    def encode_actions(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(..., A) -> nearest bin (...,) and the residual offset (..., A): bin centre + offset = action."""
        bins = torch.cdist(action.reshape(-1, self.action_dim), self.centres).argmin(-1).view(action.shape[:-1])
        return bins, action - self.centres[bins]

    def compute_loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        logits, offsets = self.heads(batch["image"], batch["agent_pos"])
        bins, target_offset = self.encode_actions(batch["action"])  # (B, Tp), (B, Tp, A)
        logp = F.log_softmax(logits, dim=-1).gather(-1, bins[..., None]).squeeze(-1)  # (B, Tp)
        focal = -((1 - logp.exp()) ** self.config.focal_gamma * logp).mean()
        chosen = offsets.gather(2, bins[..., None, None].expand(-1, -1, 1, self.action_dim)).squeeze(2)  # (B, Tp, A)
        return focal + self.config.offset_weight * F.mse_loss(chosen, target_offset)

    def predict_action_chunk(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        logits, offsets = self.call_graph("heads", obs["image"], obs["agent_pos"])
        probs = F.softmax(logits, dim=-1)  # (B, Tp, k)
        gens = self.generators(obs, logits.device)
        if isinstance(gens, torch.Generator):  # one stream for the batch
            bins = torch.multinomial(probs.flatten(0, 1), 1, generator=gens).view(logits.shape[:2])
        else:  # row i from episode i's own stream (sampled on its generator's device)
            bins = torch.stack([torch.multinomial(p.to(g.device), 1, generator=g).view(-1).to(p.device)
                                for p, g in zip(probs, gens, strict=True)])  # sample a bin, as BeT does
        chosen = offsets.gather(2, bins[..., None, None].expand(-1, -1, 1, self.action_dim)).squeeze(2)
        return self.centres[bins] + chosen  # (B, Tp, A)
