"""Inference runners for the latency benchmark: `reference` (the public code's way) and `fast` (bcbench's).

reference: fp32 eager PyTorch under `torch.no_grad`; Diffusion Policy samples with diffusers' scheduler,
           calling `scheduler.step` in a Python loop over its timesteps.
fast:      `torch.inference_mode` (no autograd bookkeeping at all), Diffusion Policy's sampler constants
           precomputed once per (sampler, steps) instead of recomputed by `step` every call, and optionally
           frozen TorchScript graphs (`--backend jit`: BatchNorm folded into the convolutions, oneDNN
           kernels on CPU). Same weights, same noise -> the same chunk as `reference` within 1e-4 (a test).
"""

from __future__ import annotations

import copy
import warnings
from typing import Any

import numpy as np
import torch

from bcbench.policies.diffusion import DiffusionPolicy
from bcbench.policies.learned import PolicyRunner
from bcbench.policies.samplers import make_diffusers_sampler, run_diffusers, run_plan
from bcbench.policies.unet1d import im2col


class ReferenceRunner(PolicyRunner):
    """The plain way: no_grad, eager fp32, diffusers' scheduler loop."""

    mode = "reference"

    @torch.no_grad()
    def predict_action_chunk(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        o = self.prepare(obs)
        model = self.model
        if isinstance(model, DiffusionPolicy):
            cond = model.encode(o["image"], o["agent_pos"])
            sched = make_diffusers_sampler(model.noise_scheduler, model.sampler_kind, model.sampler_steps,
                                           model.sampler_spacing)
            x = model.randn(o, (cond.shape[0], model.config.pred_horizon, 2), cond.device)
            gen = model.generators(o, cond.device)  # diffusers draws row by row from a list, as randn does
            chunk = run_diffusers(sched, lambda x, t: model.unet(x, torch.tensor(t, device=x.device), cond), x, gen)
        else:
            chunk = model.predict_action_chunk(o)
        return self.normalizer.unnormalize("action", chunk.float()).cpu().numpy()


class MatmulConv1d(torch.nn.Module):
    """A Conv1d evaluated as one matrix product: im2col of the input times the pre-transposed weight.

    At batch 1 the U-Net's sequences are 4-16 steps long, a shape for which the eager convolution kernels
    are slow (measured: 7.7 ms for the 1024->1024, kernel-5 layer against 2.3 ms as a matmul, and the
    weight itself streams from memory in under 1 ms). Same arithmetic, summed in another order.
    """

    def __init__(self, conv: torch.nn.Conv1d) -> None:
        super().__init__()
        k = conv.kernel_size[0]
        self.k, self.stride, self.pad = k, conv.stride[0], conv.padding[0]
        # (Cout, Cin, k) -> (Cin * k, Cout), rows ordered (channel, tap) like the unfolded input
        self.register_buffer("weight_t", conv.weight.detach().reshape(conv.out_channels, -1).t().contiguous())
        self.register_buffer("bias", None if conv.bias is None else conv.bias.detach().clone())

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, Cin, T) -> (B, Cout, T')
        out = im2col(x, self.k, self.stride, self.pad) @ self.weight_t  # (B, T', Cout)
        if self.bias is not None:
            out = out + self.bias
        return out.transpose(1, 2)


class MatmulConvTranspose1d(torch.nn.Module):
    """A ConvTranspose1d as one matrix product followed by overlap-add (fold); eager takes a slow path."""

    def __init__(self, conv: torch.nn.ConvTranspose1d) -> None:
        super().__init__()
        self.k, self.stride, self.pad = conv.kernel_size[0], conv.stride[0], conv.padding[0]
        self.out_channels = conv.out_channels
        # (Cin, Cout, k) -> (Cin, Cout * k): every input step spreads a (Cout, k) patch
        self.register_buffer("weight", conv.weight.detach().reshape(conv.in_channels, -1).contiguous())
        self.register_buffer("bias", None if conv.bias is None else conv.bias.detach().clone())

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, Cin, T) -> (B, Cout, (T-1)*s - 2p + k)
        b, _, t = x.shape
        cols = (x.transpose(1, 2) @ self.weight).transpose(1, 2)  # (B, Cout * k, T)
        full = (t - 1) * self.stride + self.k
        out = torch.nn.functional.fold(cols, output_size=(1, full), kernel_size=(1, self.k), stride=(1, self.stride))
        out = out.view(b, self.out_channels, full)[:, :, self.pad: full - self.pad]
        return out if self.bias is None else out + self.bias[:, None]


def matmul_convs(module: torch.nn.Module) -> int:
    """Replace plain Conv1d / ConvTranspose1d layers inside `module` by their matmul forms; returns count."""
    n = 0
    for name, child in module.named_children():
        if isinstance(child, torch.nn.Conv1d) and child.dilation == (1,) and child.groups == 1 \
                and child.padding_mode == "zeros" and isinstance(child.padding, tuple):
            setattr(module, name, MatmulConv1d(child))
            n += 1
        elif isinstance(child, torch.nn.ConvTranspose1d) and child.dilation == (1,) and child.groups == 1 \
                and child.output_padding == (0,):
            setattr(module, name, MatmulConvTranspose1d(child))
            n += 1
        else:
            n += matmul_convs(child)
    return n


class Int8Conv1d(torch.nn.Module):
    """MatmulConv1d with its weight as a dynamically quantised int8 Linear (fbgemm; 4x less weight traffic).

    Not exact: activations are quantised per call. Its own latency mode (`fast-int8`), whose deviation
    from the reference and score change are reported separately.
    """

    def __init__(self, conv: MatmulConv1d) -> None:
        super().__init__()
        self.k, self.stride, self.pad = conv.k, conv.stride, conv.pad
        cin_k, cout = conv.weight_t.shape
        lin = torch.nn.Linear(cin_k, cout, bias=conv.bias is not None)
        with torch.no_grad():
            lin.weight.copy_(conv.weight_t.t())
            if conv.bias is not None:
                lin.bias.copy_(conv.bias)
        with warnings.catch_warnings():  # torch.ao.quantization is deprecated upstream; it still works here
            warnings.simplefilter("ignore")
            self.lin = torch.ao.quantization.quantize_dynamic(torch.nn.Sequential(lin), {torch.nn.Linear},
                                                              dtype=torch.qint8)[0]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.lin(im2col(x, self.k, self.stride, self.pad).contiguous()).transpose(1, 2)


def int8_convs(module: torch.nn.Module) -> int:
    """Replace every MatmulConv1d inside `module` by its int8 form; returns the count."""
    n = 0
    for name, child in module.named_children():
        if isinstance(child, MatmulConv1d):
            setattr(module, name, Int8Conv1d(child))
            n += 1
        else:
            n += int8_convs(child)
    return n


class SplitFiLM:
    """Diffusion Policy's FiLM layers split into their step part and their observation part.

    Each block's FiLM is Linear(Mish([step_emb(t) ; obs])): Mish acts elementwise, so the Linear splits
    exactly into W_t Mish(step_emb(t)) + W_o Mish(obs) + b. The step part depends only on t, so it is
    computed once per sampler plan; the observation part once per call. The 18.4 M conditioning weights
    of the paper U-Net (23% of it) then leave the denoising loop, which only reads the convolutions.
    """

    def __init__(self, model: Any) -> None:
        self.model = model
        self.blocks = model.unet.residual_blocks()
        self.step_dim = model.config.step_embed_dim
        self._plan_key: Any = None
        self._step_terms: list[list[torch.Tensor]] = []

    def _linear(self, block: Any) -> torch.nn.Linear:
        return block.cond_encoder[1]

    def step_terms(self, plan: Any, device: torch.device) -> list[list[torch.Tensor]]:
        key = (tuple(plan.timesteps), plan.kind, device)
        if key != self._plan_key:
            t = torch.tensor(plan.timesteps, device=device)
            emb = torch.nn.functional.mish(self.model.unet.diffusion_step_encoder(t))  # (K, S)
            per_block = [emb @ self._linear(b).weight[:, : self.step_dim].T for b in self.blocks]  # (K, 2C)
            self._step_terms = [[pb[k : k + 1] for pb in per_block] for k in range(len(plan.timesteps))]
            self._plan_key = key
        return self._step_terms

    def obs_terms(self, cond: torch.Tensor) -> list[torch.Tensor]:
        g = torch.nn.functional.mish(cond)  # (B, G)
        return [torch.addmm(self._linear(b).bias, g, self._linear(b).weight[:, self.step_dim:].T) for b in self.blocks]


class FastRunner(PolicyRunner):
    """inference_mode + precomputed sampler constants and FiLM terms (+ optional frozen TorchScript)."""

    mode = "fast"

    @property
    def mode_name(self) -> str:
        return {"eager": "fast", "jit": "fast-jit", "int8": "fast-int8"}[self.backend]

    def __init__(self, model: Any, normalizer: Any, device: str | torch.device = "cpu", backend: str = "eager",
                 extra: dict[str, Any] | None = None) -> None:
        if backend == "jit" or isinstance(model, DiffusionPolicy):
            model = copy.deepcopy(model)  # submodules get replaced: never touch the caller's model
        super().__init__(model, normalizer, device, extra)
        self.backend = backend
        if backend in ("eager", "int8") and isinstance(self.model, DiffusionPolicy):
            matmul_convs(self.model.unet)
            if backend == "int8":
                int8_convs(self.model.unet)
        if backend == "jit":
            self._freeze()

    def _freeze(self) -> None:
        """Trace and freeze the networks (folds BatchNorm into convolutions, picks oneDNN kernels)."""
        m = self.model
        image = torch.rand(1, m.config.obs_horizon, 3, m.config.image_size, m.config.image_size, device=self.device)
        pos = torch.zeros(1, m.config.obs_horizon, 2, device=self.device)
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            if isinstance(m, DiffusionPolicy):
                cond = m.encode(image, pos)
                m.encoder = _frozen(m.encoder, (image,))
                unet = _frozen(m.unet, (torch.zeros(1, m.config.pred_horizon, 2, device=self.device),
                                        torch.tensor(1, device=self.device), cond))
                m.unet = unet
            elif getattr(m, "traceable_forward", False):
                frozen = _frozen(m, (image, pos))
                m.forward = frozen.forward  # predict_action_chunk calls self(...), i.e. the frozen graph

    @torch.inference_mode()
    def predict_action_chunk(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        m = self.model
        if not isinstance(m, DiffusionPolicy) or self.backend == "jit":
            return super().predict_action_chunk(obs)
        if getattr(self, "_film", None) is None:
            self._film = SplitFiLM(m)
        o = self.prepare(obs)
        cond = m.encode(o["image"], o["agent_pos"])  # once per call
        obs_terms = self._film.obs_terms(cond)
        step_terms = self._film.step_terms(m.plan, cond.device)
        index = {t: k for k, t in enumerate(m.plan.timesteps)}

        def denoise(x: torch.Tensor, t: int) -> torch.Tensor:
            films = [a + b for a, b in zip(obs_terms, step_terms[index[t]], strict=True)]
            return m.unet.forward_films(x, films)

        x = m.randn(o, (cond.shape[0], m.config.pred_horizon, 2), cond.device)
        chunk = run_plan(m.plan, denoise, x, lambda shape: m.randn(o, shape, cond.device))
        return self.normalizer.unnormalize("action", chunk.float()).cpu().numpy()

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "mode": self.mode_name, "backend": self.backend}


def _frozen(module: torch.nn.Module, example: tuple[torch.Tensor, ...]) -> Any:
    traced = torch.jit.trace(module.eval(), example, check_trace=False)
    return torch.jit.optimize_for_inference(torch.jit.freeze(traced))


def make_runner(mode: str, model: Any, normalizer: Any, device: str | torch.device = "cpu",
                extra: dict[str, Any] | None = None) -> PolicyRunner:
    from bcbench.errors import BCBenchError

    if mode == "reference":
        return ReferenceRunner(model, normalizer, device, extra)
    if mode == "fast":
        return FastRunner(model, normalizer, device, "eager", extra)
    if mode == "fast-jit":
        return FastRunner(model, normalizer, device, "jit", extra)
    if mode == "fast-int8":
        return FastRunner(model, normalizer, device, "int8", extra)
    raise BCBenchError(f"unknown latency mode '{mode}' (reference, fast, fast-jit, fast-int8)")
