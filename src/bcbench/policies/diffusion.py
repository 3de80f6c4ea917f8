"""Diffusion Policy (Chi et al., RSS 2023), as in its vision notebook and as the study ran it.

Vision: ResNet-18 with GroupNorm(C/16) instead of BatchNorm, no fc, global average pool -> 512 per frame;
the To=2 frame features and normalised agent positions form the global condition 2 x (512 + 2) = 1028.
Action: a 1-D conditional U-Net predicts the noise added to the normalised 16x2 chunk (epsilon
prediction, 100 training timesteps, squared-cosine or linear betas, samples clipped to [-1, 1]).
Sampling: DDPM or DDIM with any step count and timestep spacing, chosen at evaluation time (`set_sampler`);
the observation is encoded once per call and only the U-Net runs K times (bcbench.policies.denoiser).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from bcbench.errors import BCBenchError
from bcbench.policies.config import OptimConfig, cpu_profile, pick_preset
from bcbench.policies.denoiser import DenoiserNetConfig, DenoiserPolicy
from bcbench.policies.guidance import Guide, inpaint_clean
from bcbench.policies.prefix import Prefix, masked_mse, train_prefix
from bcbench.policies.samplers import DEFAULT_SPACING, check_spacing, make_train_scheduler, plan, run_plan
from bcbench.tasks import Task


@dataclass
class DiffusionConfig(DenoiserNetConfig):
    num_train_timesteps: int = 100
    """diffusion steps at training"""
    beta_schedule: str = "squaredcos_cap_v2"
    """squaredcos_cap_v2 (the study's cosine) or linear (the study's Figure 4 re-training)"""
    sampler: str = "ddpm"
    """default sampler at evaluation: ddpm or ddim (bcbench eval --sampler overrides)"""
    sampling_steps: int = 100
    """default denoising steps at evaluation (bcbench eval --steps overrides)"""
    sampling_spacing: str = DEFAULT_SPACING
    """timesteps visited at evaluation: trailing (always starts at t = 99) or leading (diffusers' and the
    study's default; see bcbench.policies.samplers); bcbench eval --spacing overrides"""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.beta_schedule not in ("squaredcos_cap_v2", "linear"):
            raise BCBenchError(f"beta_schedule must be squaredcos_cap_v2 or linear, got '{self.beta_schedule}'")
        if self.sampler not in ("ddpm", "ddim") or not 1 <= self.sampling_steps <= self.num_train_timesteps:
            raise BCBenchError("sampler must be ddpm or ddim with 1 <= sampling_steps <= num_train_timesteps")
        check_spacing(self.sampling_spacing)

    @classmethod
    def preset(cls, name: str) -> DiffusionConfig:
        def quick() -> DiffusionConfig:
            # CPU-sized: 1/4-width ResNet-18 with one block per stage, a 64/128/256 U-Net, a higher learning
            # rate, 8 epochs (2,736 steps, about 15 minutes on 2 cores).
            return cls(encoder_width=16, encoder_layers=(1, 1, 1, 1), down_dims=(64, 128, 256), step_embed_dim=64,
                       optim=OptimConfig(optimizer="adamw", lr=5e-4, betas=(0.95, 0.999), weight_decay=1e-6,
                                         schedule="cosine", warmup_steps=200, epochs=8, batch_size=64, ema=True,
                                         ema_power=0.75, ema_max_decay=0.9999, checkpoint_every=200))

        def cpu() -> DiffusionConfig:
            # the quick network, recipe B of studies/cpu-explore-dpflow.toml (20,400 steps x 64, lr 5e-4: 1.31 M
            # samples), chosen on validation seeds over recipe A (5,100 x 256, lr 1e-3) for DP and flow alike
            # (results/cpu-explore-dpflow/README.md); flow's `cpu` preset is this one with its own objective
            return cpu_profile(quick(), epochs=60, batch_size=64, lr=5e-4, warmup_steps=100, max_steps=20400)

        # every preset with the cosine (squaredcos_cap_v2) schedule, and as NAME_linear with linear betas
        base = {"quick": quick, "cpu": cpu, "paper": cls}
        table = {**base, **{f"{k}_linear": (lambda b=b: dataclasses.replace(b(), beta_schedule="linear"))
                            for k, b in base.items()}}
        return pick_preset("diffusion", name, table)


class DiffusionPolicy(DenoiserPolicy):
    name = "diffusion"
    samplers = ("ddpm", "ddim")
    guidance_autograd = False  # RTC inpaints the clean estimate: no backward pass, every backend

    def __init__(self, config: DiffusionConfig, task: Task | None = None) -> None:
        super().__init__(config, task)
        c = config
        self.noise_scheduler = make_train_scheduler(c.num_train_timesteps, c.beta_schedule)
        ac = self.noise_scheduler.alphas_cumprod.float()
        self.register_buffer("sqrt_ac", ac.sqrt(), persistent=False)  # for add_noise, on the model's device
        self.register_buffer("sqrt_1m_ac", (1 - ac).sqrt(), persistent=False)
        self.set_sampler(c.sampler, c.sampling_steps, c.sampling_spacing)

    def set_sampler(self, kind: str, steps: int, spacing: str | None = None) -> None:
        """Choose DDPM/DDIM, the number of denoising steps and their spacing for inference (no retraining)."""
        spacing = spacing or self.config.sampling_spacing
        self.plan = plan(self.noise_scheduler, kind, steps, spacing)
        self.sampler_kind, self.sampler_steps, self.sampler_spacing = kind, steps, spacing

    def compute_loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        cond = self.encode(batch["image"], batch["agent_pos"])
        action = batch["action"]  # (B, Tp, A) in [-1, 1]
        noise = self.train_draw(batch, torch.randn, tuple(action.shape[1:]))
        n_t = self.config.num_train_timesteps
        t = (self.train_draw(batch, torch.rand) * n_t).long().clamp_(max=n_t - 1)  # uniform over 0..n_t-1
        noisy = self.sqrt_ac[t, None, None] * action + self.sqrt_1m_ac[t, None, None] * noise
        if not self.delay_conditioned:
            return F.mse_loss(self.unet(noisy, t, cond), noise)
        # training-time RTC: a prefix of clean actions (as at timestep 0) in place of noise, left out of the loss;
        # drawn after the noise and times, so those are what an unconditioned run draws
        prefix = train_prefix(self, batch, self.config.delay_train, self.config.obs_horizon - 1)
        return masked_mse(self.unet(prefix.network_input(noisy), t, cond), noise, prefix.mask)

    def predict_action_chunk(self, obs: dict[str, torch.Tensor], guide: Guide | None = None,
                             prefix: Prefix | None = None) -> torch.Tensor:
        """Denoise from pure noise; with `guide`, every clean estimate is inpainted towards the target (Real-Time
        Chunking carried over to epsilon prediction without the Jacobian: bcbench.policies.guidance); with `prefix`
        (a delay-conditioned network only), its actions are given clean at every step (bcbench.policies.prefix)."""
        self.check_prefix(prefix)
        model, b, device = self.denoiser(obs, self.plan.timesteps)  # the observation is encoded once
        model = self.prefixed(model, prefix)
        edit = None
        if guide is not None:
            ac = self.noise_scheduler.alphas_cumprod

            def edit(x0: torch.Tensor, t: int) -> torch.Tensor:
                return inpaint_clean(x0, float(ac[t]), guide)

        x = self.randn(obs, (b, self.config.pred_horizon, self.action_dim), device)  # (B, Tp, A) pure noise
        x = run_plan(self.plan, model, x, lambda shape: self.randn(obs, shape, device), edit)
        return x if prefix is None else prefix.impose(x)  # the prefix is what executes: returned as given
