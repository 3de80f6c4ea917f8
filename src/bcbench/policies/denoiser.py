"""Diffusion Policy's networks and inference path, shared by `diffusion` and `flow` (same sizes, same code).

Networks (Chi et al., RSS 2023): a ResNet-18 with GroupNorm per frame -> global condition
To x (512 + 2); a 1-D conditional U-Net whose residual blocks are FiLM-conditioned on [step ; condition].
Inference: the observation is encoded once per call; the generative family (DDPM/DDIM, flow) supplies the
times its sampler visits and the loop; the U-Net runs once per visited time.

The one inference path, two exact forms behind `split_film`:
- False ("reference", the paper code's way): the plain U-Net at every step, unet(x, t, condition).
- True (the default): FiLM split into its observation part (graph `obs_film`, once per call) and its step
  part (once per visited time, for the whole batch), so each step runs graph `denoise(x, film)`, which
  reads only the convolutions. Equal to the reference within float rounding (a test: 1e-4).
Deployment backends (bcbench.evaluation.backends) compile `obs_film` and `denoise`; the loop stays here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import torch

from bcbench.errors import BCBenchError
from bcbench.policies.config import OptimConfig, PolicyConfig
from bcbench.policies.encoders import RESNET18_LAYERS, FrameFeatures, count_parameters
from bcbench.policies.learned import BCPolicy
from bcbench.policies.prefix import Prefix, check_delay_range
from bcbench.policies.unet1d import ConditionalUnet1D
from bcbench.tasks import Task


def _paper_optim() -> OptimConfig:
    return OptimConfig(optimizer="adamw", lr=1e-4, betas=(0.95, 0.999), weight_decay=1e-6, schedule="cosine",
                       warmup_steps=500, epochs=100, batch_size=64, ema=True, ema_power=0.75, ema_max_decay=0.9999)


@dataclass
class DenoiserNetConfig(PolicyConfig):
    """Diffusion Policy's networks (ResNet-18/GroupNorm encoder, 1-D conditional U-Net): shared with `flow`."""

    encoder_width: int = 64
    """ResNet-18 base width (64 = the real ResNet-18, 512 features per frame)"""
    encoder_layers: tuple[int, ...] = RESNET18_LAYERS
    """basic blocks per ResNet stage"""
    down_dims: tuple[int, ...] = (256, 512, 1024)
    """U-Net channel widths per level"""
    kernel_size: int = 5
    """U-Net convolution kernel"""
    n_groups: int = 8
    """GroupNorm groups in the U-Net"""
    step_embed_dim: int = 256
    """sinusoidal diffusion-step (or flow-time) embedding size"""
    crop: int | None = 84
    """random crop size at training (centre crop at evaluation); None = no crop"""
    delay_train: tuple[int, int] = (0, 0)
    """training-time delay conditioning (training-time RTC, Black et al. 2025, arXiv 2512.05964;
    bcbench.policies.prefix): (lo, hi) control steps; each training chunk draws d uniformly from lo..hi and its d
    actions from the current step on are given clean and left out of the loss, which `--strategy prefix` then feeds
    with the executing chunk's actions. hi > 0 adds a clean-position mask channel to the U-Net's input; (0, 0):
    off, today's network exactly"""
    optim: OptimConfig = field(default_factory=_paper_optim)

    def __post_init__(self) -> None:
        super().__post_init__()
        self.encoder_layers, self.down_dims = tuple(self.encoder_layers), tuple(self.down_dims)
        self.delay_train = check_delay_range(tuple(self.delay_train), self.obs_horizon, self.pred_horizon)
        if self.crop is not None and not 8 <= self.crop <= self.image_size:
            raise BCBenchError(f"crop must be in 8..{self.image_size} or None, got {self.crop}")
        if any(d % self.n_groups for d in self.down_dims) or self.encoder_width % 16:
            raise BCBenchError("down_dims must divide by n_groups and encoder_width by 16 (GroupNorm C/16)")
        if self.pred_horizon % 2 ** (len(self.down_dims) - 1):
            raise BCBenchError(f"pred_horizon must divide by {2 ** (len(self.down_dims) - 1)} for the U-Net")


class DenoiserPolicy(BCPolicy):
    """Encoder + conditional U-Net, and the denoiser the samplers of `diffusion` and `flow` call."""

    graphs = ("obs_film", "denoise")
    loop_graphs = ("denoise",)
    split_film = True  # False: the reference form (plain U-Net per step); see the module docstring
    guidable = True  # Real-Time Chunking's guided sampling (bcbench.policies.guidance)
    encodes_once = True  # obs["samples"] = n: BID's candidates share one encoding of their observation

    def __init__(self, config: DenoiserNetConfig, task: Task | None = None) -> None:
        super().__init__()
        self.config = c = config
        self.use_task(task)
        self.encoder = FrameFeatures("group", c.encoder_width, c.encoder_layers, c.crop)
        # delay conditioning reads a clean-action mask beside the action channels (bcbench.policies.prefix);
        # without it the U-Net is Diffusion Policy's, parameter for parameter
        self.delay_conditioned = c.delay_train[1] > 0
        a = self.action_dim
        self.unet = ConditionalUnet1D(a + 1 if self.delay_conditioned else a,
                                      c.obs_horizon * (self.encoder.out_dim + self.state_dim),
                                      c.step_embed_dim, c.down_dims, c.kernel_size, c.n_groups,
                                      out_dim=a if self.delay_conditioned else None)

    def encode(self, image: torch.Tensor, agent_pos: torch.Tensor) -> torch.Tensor:
        """image (B, To, 3, H, W), agent_pos (B, To, S) -> global condition (B, To * (F + S))."""
        feats = self.encoder(image)  # (B, To, F)
        return torch.cat([feats, agent_pos], dim=-1).flatten(1)

    def obs_film(self, image: torch.Tensor, agent_pos: torch.Tensor) -> torch.Tensor:
        """Graph: observations -> the observation part of every block's FiLM (B, F)."""
        return self.unet.obs_film(self.encode(image, agent_pos))

    def denoise(self, x: torch.Tensor, film: torch.Tensor) -> torch.Tensor:
        """Graph: one U-Net evaluation given all FiLM terms: x (B, Tp, A), film (B, F) -> (B, Tp, A). Traced for
        export (OpenVINO, ONNX Runtime) in the U-Net's channels-last matrix form, the faster one there."""
        return self.unet.forward_film(x, film, time_last=torch.jit.is_tracing())

    def graph_inputs(self, batch: int = 1) -> dict[str, tuple[torch.Tensor, ...]]:
        obs = self.example_obs(batch)
        image, pos = obs["image"], obs["agent_pos"]
        with torch.no_grad():
            film = self.obs_film(image, pos)
        # the state x, and a delay-conditioned network's mask channel beside it
        x = torch.randn(batch, self.config.pred_horizon, self.action_dim + int(self.delay_conditioned))
        return {"obs_film": (image, pos), "denoise": (x, film)}

    def net_input(self, x: torch.Tensor, prefix: Prefix | None) -> torch.Tensor:
        """What the U-Net reads for state x (B, Tp, A): x itself, or for a delay-conditioned network [x with the prefix
        imposed ; its mask] (an all-zero mask without a prefix)."""
        if not self.delay_conditioned:
            return x
        if prefix is None:
            return torch.cat([x, x.new_zeros(*x.shape[:-1], 1)], dim=-1)
        return prefix.network_input(x)

    def check_prefix(self, prefix: Prefix | None) -> None:
        if prefix is not None and not self.delay_conditioned:
            raise BCBenchError(f"{self.name} was trained without delay conditioning (delay_train = (0, 0)): it cannot "
                               "take a clean prefix; train with --set delay_train=[LO,HI]")

    def prefixed(self, model: Callable[[torch.Tensor, float], torch.Tensor], prefix: Prefix | None
                 ) -> Callable[[torch.Tensor, float], torch.Tensor]:
        """The denoiser of a sampler's loop with the prefix re-imposed at every network evaluation (identity for a
        network without the mask channel)."""
        if not self.delay_conditioned:
            return model
        return lambda x, t: model(self.net_input(x, prefix), t)

    def denoiser(self, obs: dict[str, torch.Tensor], times: Sequence[float]
                 ) -> tuple[Callable[[torch.Tensor, float], torch.Tensor], int, torch.device]:
        """model(x, t) for every time t in `times` (the U-Net's step scale), the batch size and device."""
        image, pos = obs["image"], obs["agent_pos"]
        n = int(obs.get("samples", 1))  # samples per observation row (rows repeated in place)
        if not self.split_film:
            cond = self.encode(image, pos)  # (B, G), once per call
            cond = cond.repeat_interleave(n, 0) if n > 1 else cond  # (B n, G)
            return (lambda x, t: self.unet(x, torch.tensor(t, device=x.device), cond)), cond.shape[0], cond.device
        film = self.call_graph("obs_film", image, pos)  # (B, F), once per call
        film = film.repeat_interleave(n, 0) if n > 1 else film  # (B n, F)
        visited = list(dict.fromkeys(times))
        steps = self._step_films(visited, film.device)  # (K, F), for the whole batch
        row = {t: i for i, t in enumerate(visited)}
        return (lambda x, t: self.call_graph("denoise", x, film + steps[row[t]])), film.shape[0], film.device

    def _step_films(self, visited: list[float], device: torch.device) -> torch.Tensor:
        """unet.step_film of the visited times, kept while the weights it reads are unchanged.

        The key holds each weight's storage and in-place version counter, so an optimiser step, a loaded
        checkpoint or a move to another device recomputes it (5 ms a call for the paper U-Net otherwise).
        """
        params = [*self.unet.diffusion_step_encoder.parameters(),
                  *(b.cond_encoder[1].weight for b in self.unet.residual_blocks())]
        key = (tuple(visited), device, tuple((p.data_ptr(), p._version) for p in params))
        if getattr(self, "_step_cache", (None,))[0] != key:
            with torch.no_grad():
                self._step_cache = (key, self.unet.step_film(torch.tensor(visited, device=device)))
        return self._step_cache[1]

    def parameter_breakdown(self) -> dict[str, int]:
        return {"encoder": count_parameters(self.encoder), "unet": count_parameters(self.unet),
                "total": self.num_parameters()}
