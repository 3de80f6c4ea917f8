"""The 1-D conditional U-Net noise-prediction network of Diffusion Policy (Chi et al., RSS 2023).

It denoises an action chunk (B, Tp, Da), treated as Da channels over Tp time steps. Conditioning
(sinusoidal diffusion-step embedding through an MLP, concatenated with the observation features) enters
every residual block through FiLM: a per-channel scale and bias computed from the condition. Down path
with stride-2 convolutions, two middle blocks, transposed-convolution up path with skip connections.
At the study's size (down dims 256/512/1024, kernel 5, 8 groups, step embedding 256, condition
256 + 1028) it has 79,947,266 parameters.
"""

from __future__ import annotations

import itertools
import math
import typing

import torch
import torch.nn.functional as F
from torch import nn


class SinusoidalPosEmb(nn.Module):
    """Transformer-style sinusoidal embedding of the (integer) diffusion step."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.dim = dim

    def forward(self, t: torch.Tensor) -> torch.Tensor:  # (B,) -> (B, dim)
        half = self.dim // 2
        freqs = torch.exp(torch.arange(half, device=t.device) * -(math.log(10000) / (half - 1)))
        args = t.float()[:, None] * freqs[None, :]
        return torch.cat([args.sin(), args.cos()], dim=-1)


def im2col(x: torch.Tensor, k: int, stride: int, pad: int) -> torch.Tensor:
    """(B, Cin, T) -> (B, T', Cin * k): each output step's receptive field as one row, (channel, tap) order."""
    if k == 1 and stride == 1:
        return x.transpose(1, 2)
    xp = nn.functional.pad(x, (pad, pad)) if pad else x
    u = xp.unfold(2, k, stride)  # (B, Cin, T', k)
    return u.transpose(1, 2).reshape(x.shape[0], u.shape[2], -1)


class Conv1d(nn.Conv1d):
    """nn.Conv1d (same parameters and state dict) that on a CPU runs wide layers as one matrix product.

    oneDNN's 1-D convolution kernels are slow for the U-Net's shapes (4-16 time steps, 256-1024 channels):
    measured at batch 256 on 2 cores, forward + backward of a 512->512 kernel-5 layer takes 146 ms as a
    convolution and 39 ms as im2col + matmul in bf16 (103 vs 77 ms in fp32); narrow layers are as fast or
    faster as convolutions. Same arithmetic, summed in another order (equal to float tolerance).
    """

    # Cin * k from which the matmul wins, under bf16 autocast (True) and in fp32 (False)
    MATMUL_MIN_FAN_IN: typing.ClassVar[dict[bool, int]] = {True: 1280, False: 2560}

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, Cin, T) -> (B, Cout, T')
        fan_in = self.in_channels * self.kernel_size[0]
        # exported graphs (OpenVINO) keep the convolution: the runtime picks its own kernels for it
        if x.device.type != "cpu" or fan_in < self.MATMUL_MIN_FAN_IN[torch.is_autocast_enabled("cpu")] or \
                torch.jit.is_tracing():
            return super().forward(x)
        out = im2col(x, self.kernel_size[0], self.stride[0], self.padding[0]) @ self.weight.reshape(
            self.out_channels, -1).t()  # (B, T', Cout)
        if self.bias is not None:
            out = out + self.bias
        return out.transpose(1, 2)


class Conv1dBlock(nn.Sequential):
    """Conv1d -> GroupNorm -> Mish."""

    def __init__(self, cin: int, cout: int, kernel: int, groups: int) -> None:
        super().__init__(Conv1d(cin, cout, kernel, padding=kernel // 2), nn.GroupNorm(groups, cout), nn.Mish())


class ConditionalResidualBlock1D(nn.Module):
    """Two conv blocks; FiLM (scale, bias per channel, from the condition) between them; 1x1 residual."""

    def __init__(self, cin: int, cout: int, cond_dim: int, kernel: int, groups: int) -> None:
        super().__init__()
        self.blocks = nn.ModuleList([Conv1dBlock(cin, cout, kernel, groups), Conv1dBlock(cout, cout, kernel, groups)])
        self.out_channels = cout
        self.cond_encoder = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, 2 * cout))
        self.residual_conv = Conv1d(cin, cout, 1) if cin != cout else nn.Identity()

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:  # x (B, Cin, T), cond (B, cond_dim)
        return self.forward_film(x, self.cond_encoder(cond))

    def forward_film(self, x: torch.Tensor, film: torch.Tensor) -> torch.Tensor:
        """The block given its FiLM parameters (B, 2 * Cout) already computed."""
        out = self.blocks[0](x)  # (B, Cout, T)
        film = film.view(-1, 2, self.out_channels, 1)  # (B, 2, Cout, 1)
        out = film[:, 0] * out + film[:, 1]  # FiLM: the condition rescales and shifts every channel
        out = self.blocks[1](out)
        return out + self.residual_conv(x)


class ConditionalUnet1D(nn.Module):
    def __init__(self, input_dim: int, global_cond_dim: int, step_embed_dim: int = 256,
                 down_dims: tuple[int, ...] = (256, 512, 1024), kernel: int = 5, groups: int = 8) -> None:
        super().__init__()
        self.step_embed_dim = step_embed_dim
        self.diffusion_step_encoder = nn.Sequential(
            SinusoidalPosEmb(step_embed_dim), nn.Linear(step_embed_dim, step_embed_dim * 4), nn.Mish(),
            nn.Linear(step_embed_dim * 4, step_embed_dim),
        )
        cond_dim = step_embed_dim + global_cond_dim
        dims = [input_dim, *down_dims]
        in_out = list(itertools.pairwise(dims))

        def block(cin: int, cout: int) -> ConditionalResidualBlock1D:
            return ConditionalResidualBlock1D(cin, cout, cond_dim, kernel, groups)

        self.down_modules = nn.ModuleList()
        for i, (cin, cout) in enumerate(in_out):
            last = i == len(in_out) - 1
            self.down_modules.append(nn.ModuleList([
                block(cin, cout), block(cout, cout), Conv1d(cout, cout, 3, 2, 1) if not last else nn.Identity()]))
        mid = down_dims[-1]
        self.mid_modules = nn.ModuleList([block(mid, mid), block(mid, mid)])
        self.up_modules = nn.ModuleList()
        # One up level per down level but the first; each upsamples, undoing the down path's strides.
        for cin, cout in reversed(in_out[1:]):
            self.up_modules.append(nn.ModuleList([
                block(cout * 2, cin), block(cin, cin), nn.ConvTranspose1d(cin, cin, 4, 2, 1)]))
        self.final_conv = nn.Sequential(Conv1dBlock(down_dims[0], down_dims[0], kernel, groups),
                                        Conv1d(down_dims[0], input_dim, 1))

    def residual_blocks(self) -> list[ConditionalResidualBlock1D]:
        """Every conditional block, in the order `forward` runs them."""
        out = [b for level in self.down_modules for b in level[:2]]
        out += list(self.mid_modules)
        return out + [b for level in self.up_modules for b in level[:2]]

    # Split FiLM. Each block's FiLM is Linear(Mish([step_emb(t) ; obs])): Mish acts elementwise, so the
    # Linear splits exactly into W_t Mish(step_emb(t)) + W_o Mish(obs) + b. The observation part is then
    # computed once per policy call and the step part once per visited time, and the denoising loop reads
    # only the convolutions (the conditioning weights are 23% of the paper U-Net). F = sum of 2 * Cout.
    def obs_film(self, global_cond: torch.Tensor) -> torch.Tensor:
        """The observation part of every block's FiLM (bias included): (B, G) -> (B, F)."""
        g = F.mish(global_cond)
        s = self.step_embed_dim
        return torch.cat([F.linear(g, b.cond_encoder[1].weight[:, s:], b.cond_encoder[1].bias)
                          for b in self.residual_blocks()], dim=-1)

    def step_film(self, timesteps: torch.Tensor) -> torch.Tensor:
        """The step part of every block's FiLM: timesteps (K,) -> (K, F)."""
        emb = F.mish(self.diffusion_step_encoder(timesteps))  # (K, S)
        s = self.step_embed_dim
        return torch.cat([emb @ b.cond_encoder[1].weight[:, :s].T for b in self.residual_blocks()], dim=-1)

    def forward_film(self, sample: torch.Tensor, film: torch.Tensor) -> torch.Tensor:
        """`forward` given the FiLM parameters of all blocks, obs_film + step_film: (B, Tp, Da), (B, F)."""
        films = iter(film.split([2 * b.out_channels for b in self.residual_blocks()], dim=-1))
        x = sample.transpose(1, 2)  # (B, Da, Tp)
        skips = []
        for res1, res2, down in self.down_modules:
            x = res2.forward_film(res1.forward_film(x, next(films)), next(films))
            skips.append(x)
            x = down(x)
        for res in self.mid_modules:
            x = res.forward_film(x, next(films))
        for res1, res2, up in self.up_modules:
            x = torch.cat([x, skips.pop()], dim=1)
            x = up(res2.forward_film(res1.forward_film(x, next(films)), next(films)))
        return self.final_conv(x).transpose(1, 2)

    def forward(self, sample: torch.Tensor, timestep: torch.Tensor, global_cond: torch.Tensor) -> torch.Tensor:
        """sample (B, Tp, Da), timestep (B,) or scalar, global_cond (B, G) -> predicted noise (B, Tp, Da)."""
        x = sample.transpose(1, 2)  # (B, Da, Tp)
        if timestep.ndim == 0:
            timestep = timestep.expand(x.shape[0])
        cond = torch.cat([self.diffusion_step_encoder(timestep), global_cond], dim=-1)  # (B, cond_dim)
        skips = []
        for res1, res2, down in self.down_modules:
            x = res2(res1(x, cond), cond)
            skips.append(x)
            x = down(x)  # Tp 16 -> 8 -> 4 (the last level keeps its length)
        for res in self.mid_modules:
            x = res(x, cond)
        for res1, res2, up in self.up_modules:
            x = torch.cat([x, skips.pop()], dim=1)  # skip connection doubles the channels
            x = up(res2(res1(x, cond), cond))
        return self.final_conv(x).transpose(1, 2)  # (B, Tp, Da)
