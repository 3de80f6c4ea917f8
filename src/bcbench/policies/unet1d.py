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


def unfold_time(x: torch.Tensor, k: int, stride: int, pad: int) -> torch.Tensor:
    """(B, T, C) -> (B, T', k * C): each output step's receptive field as one row, (tap, channel) order.

    Built from k strided slices of the padded input (a concatenation, no gather): what an exporter turns into
    cheap copies ahead of one fully connected layer."""
    if k == 1 and stride == 1:
        return x
    xp = F.pad(x, (0, 0, pad, pad)) if pad else x
    t_out = (x.shape[1] + 2 * pad - k) // stride + 1
    return torch.cat([xp[:, j:j + stride * (t_out - 1) + 1:stride] for j in range(k)], dim=-1)


def group_norm_time_last(gn: nn.GroupNorm, x: torch.Tensor) -> torch.Tensor:
    """nn.GroupNorm on (B, T, C) (channels last): statistics over each group's channels and every step."""
    b, t, c = x.shape
    g = x.reshape(b, t, gn.num_groups, c // gn.num_groups)  # (B, T, G, C/G)
    mean = g.mean(dim=(1, 3), keepdim=True)
    var = (g - mean).pow(2).mean(dim=(1, 3), keepdim=True)  # biased, as GroupNorm's
    return ((g - mean) / torch.sqrt(var + gn.eps)).reshape(b, t, c) * gn.weight + gn.bias


class Conv1d(nn.Conv1d):
    """nn.Conv1d (same parameters and state dict) that on a CPU runs wide layers as one matrix product.

    oneDNN's 1-D convolution kernels are slow for the U-Net's shapes (4-16 time steps, 256-1024 channels):
    measured at batch 256 on 2 cores, forward + backward of a 512->512 kernel-5 layer takes 146 ms as a
    convolution and 39 ms as im2col + matmul in bf16 (103 vs 77 ms in fp32); narrow layers are as fast or
    faster as convolutions. Same arithmetic, summed in another order (equal to float tolerance).
    `forward_time_last` is the channels-last form the exported graphs use (see ConditionalUnet1D.forward_film).
    """

    # Cin * k from which the matmul wins, under bf16 autocast (True) and in fp32 (False)
    MATMUL_MIN_FAN_IN: typing.ClassVar[dict[bool, int]] = {True: 1280, False: 2560}

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, Cin, T) -> (B, Cout, T')
        fan_in = self.in_channels * self.kernel_size[0]
        if x.device.type != "cpu" or fan_in < self.MATMUL_MIN_FAN_IN[torch.is_autocast_enabled("cpu")]:
            return super().forward(x)
        out = im2col(x, self.kernel_size[0], self.stride[0], self.padding[0]) @ self.weight.reshape(
            self.out_channels, -1).t()  # (B, T', Cout)
        if self.bias is not None:
            out = out + self.bias
        return out.transpose(1, 2)

    def forward_time_last(self, x: torch.Tensor) -> torch.Tensor:  # (B, T, Cin) -> (B, T', Cout)
        k = self.kernel_size[0]
        w = self.weight.permute(0, 2, 1).reshape(self.out_channels, k * self.in_channels)  # (tap, channel) order
        return F.linear(unfold_time(x, k, self.stride[0], self.padding[0]), w, self.bias)


class UpConv1d(nn.ConvTranspose1d):
    """nn.ConvTranspose1d(C, C, 4, stride 2, padding 1) (same state dict) with a channels-last matrix form.

    Output step o receives input step i through tap j = o - 2i + 1, so even steps 2m read taps 1 and 3 of
    inputs m and m - 1, odd steps 2m + 1 taps 2 and 0 of inputs m and m + 1: two products over pairs of
    neighbouring steps, interleaved. (OpenVINO's transposed convolution took 2.95 ms for the two layers' 5.2 MB
    at batch 1 on an AMD EPYC with AVX2, about ten times their read time: results/latency-graph-form.)
    """

    def __init__(self, channels: int) -> None:
        super().__init__(channels, channels, 4, 2, 1)

    def forward_time_last(self, x: torch.Tensor) -> torch.Tensor:  # (B, T, C) -> (B, 2T, C)
        w, t = self.weight, x.shape[1]  # w (Cin, Cout, 4)
        xp = F.pad(x, (0, 0, 1, 1))  # (B, T + 2, C): xp[m] = x[m - 1]
        prev, cur, nxt = xp[:, :t], xp[:, 1:t + 1], xp[:, 2:]
        even = F.linear(torch.cat([prev, cur], -1), torch.cat([w[:, :, 3], w[:, :, 1]]).T, self.bias)
        odd = F.linear(torch.cat([cur, nxt], -1), torch.cat([w[:, :, 2], w[:, :, 0]]).T, self.bias)
        return torch.stack([even, odd], dim=2).reshape(x.shape[0], 2 * t, -1)  # (B, T, 2, C) -> (B, 2T, C)


def run_layer(layer: nn.Module, x: torch.Tensor, time_last: bool) -> torch.Tensor:
    """A U-Net layer in either layout (an nn.Identity works on both)."""
    return layer.forward_time_last(x) if time_last and not isinstance(layer, nn.Identity) else layer(x)


class Conv1dBlock(nn.Sequential):
    """Conv1d -> GroupNorm -> Mish."""

    def __init__(self, cin: int, cout: int, kernel: int, groups: int) -> None:
        super().__init__(Conv1d(cin, cout, kernel, padding=kernel // 2), nn.GroupNorm(groups, cout), nn.Mish())

    def forward_time_last(self, x: torch.Tensor) -> torch.Tensor:  # (B, T, Cin) -> (B, T, Cout)
        return F.mish(group_norm_time_last(self[1], self[0].forward_time_last(x)))


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

    def forward_film(self, x: torch.Tensor, film: torch.Tensor, time_last: bool = False) -> torch.Tensor:
        """The block given its FiLM parameters (B, 2 * Cout) already computed; x (B, Cin, T), or (B, T, Cin)
        when `time_last`."""
        out = run_layer(self.blocks[0], x, time_last)  # (B, Cout, T), or (B, T, Cout) when time_last
        film = film.view(-1, 2, 1, self.out_channels) if time_last else film.view(-1, 2, self.out_channels, 1)
        out = film[:, 0] * out + film[:, 1]  # FiLM: the condition rescales and shifts every channel
        out = run_layer(self.blocks[1], out, time_last)
        return out + run_layer(self.residual_conv, x, time_last)


class ConditionalUnet1D(nn.Module):
    def __init__(self, input_dim: int, global_cond_dim: int, step_embed_dim: int = 256,
                 down_dims: tuple[int, ...] = (256, 512, 1024), kernel: int = 5, groups: int = 8,
                 out_dim: int | None = None) -> None:
        """`out_dim`: output channels when they differ from the input's (None: input_dim, Diffusion Policy's U-Net):
        a delay-conditioned denoiser reads the actions and a clean-position mask (3 channels) and predicts 2."""
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
                block(cout * 2, cin), block(cin, cin), UpConv1d(cin)]))
        self.final_conv = nn.Sequential(Conv1dBlock(down_dims[0], down_dims[0], kernel, groups),
                                        Conv1d(down_dims[0], out_dim or input_dim, 1))

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

    def forward_film(self, sample: torch.Tensor, film: torch.Tensor, time_last: bool = False) -> torch.Tensor:
        """`forward` given the FiLM parameters of all blocks, obs_film + step_film: (B, Tp, Da), (B, F).

        `time_last`: the same arithmetic on (B, T, C) activations, every convolution one fully connected
        product over its unfolded input (no transposes, no convolution kernels). It is the form the exporters
        trace: in OpenVINO fp32 on an AMD EPYC with AVX2 one paper-size step took 26.5 vs 31.4 ms at batch 1
        and 431 vs 801 ms at batch 50, interleaved (results/latency-graph-form). In torch it would permute the
        weights on every call, so the torch modes keep channels first.
        """
        films = iter(film.split([2 * b.out_channels for b in self.residual_blocks()], dim=-1))
        x = sample if time_last else sample.transpose(1, 2)  # (B, Tp, Da) or (B, Da, Tp)
        skips = []
        for res1, res2, down in self.down_modules:
            x = res2.forward_film(res1.forward_film(x, next(films), time_last), next(films), time_last)
            skips.append(x)
            x = run_layer(down, x, time_last)
        for res in self.mid_modules:
            x = res.forward_film(x, next(films), time_last)
        for res1, res2, up in self.up_modules:
            x = torch.cat([x, skips.pop()], dim=-1 if time_last else 1)
            x = run_layer(up, res2.forward_film(res1.forward_film(x, next(films), time_last), next(films),
                                                time_last), time_last)
        if time_last:
            return self.final_conv[1].forward_time_last(self.final_conv[0].forward_time_last(x))
        return self.final_conv(x).transpose(1, 2)

    def forward(self, sample: torch.Tensor, timestep: torch.Tensor, global_cond: torch.Tensor) -> torch.Tensor:
        """sample (B, Tp, Da), timestep (B,) or scalar, global_cond (B, G) -> predicted noise (B, Tp, out_dim)."""
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
