"""Flow-matching policy on Diffusion Policy's network: a few-step generative policy.

Same observation encoder (ResNet-18/GroupNorm) and 1-D conditional U-Net as `diffusion`, at the same sizes
in every profile, so the parameter counts are equal; only the objective and the sampler differ.
Training (rectified flow; Lipman et al., 2023; Liu et al., 2023): draw Gaussian noise e and a time t in
[0, 1], interpolate x_t = (1 - t) e + t a between the noise (t = 0) and the normalised action chunk a
(t = 1), and regress the constant velocity a - e with the U-Net (t enters through its step embedding as
100 t, the range of Diffusion Policy's integer steps). Sampling integrates dx/dt = v(x, t) from noise with
K Euler steps (one network call each) or K midpoint steps (two calls each); K = 1 is a single call.

Time sampling: t = 1 - s with s ~ Beta(1.5, 1), as pi0 does (Black et al., 2024). It puts more training
weight near the noise end (t -> 0), which is where a one- or two-step sampler takes its first, largest
step; uniform t spends as much effort near the data, where few-step sampling never evaluates the field.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from bcbench.errors import BCBenchError
from bcbench.policies.denoiser import DenoiserNetConfig, DenoiserPolicy
from bcbench.policies.diffusion import DiffusionConfig
from bcbench.policies.guidance import Guide, guided_velocity
from bcbench.policies.prefix import Prefix, masked_mse, train_prefix
from bcbench.tasks import Task

INTEGRATORS = ("euler", "midpoint")
TIME_SCALE = 100.0  # t in [0, 1] enters the U-Net's sinusoidal step embedding as 100 t


@dataclass
class FlowConfig(DenoiserNetConfig):
    """Diffusion Policy's networks (the same fields and sizes), with a flow-matching objective and sampler."""

    time_beta: tuple[float, float] = (1.5, 1.0)
    """training times t = 1 - s, s ~ Beta(a, b): pi0's choice, weighted towards the noise end"""
    sampler: str = "euler"
    """integrator at evaluation: euler (one call per step) or midpoint (two)"""
    sampling_steps: int = 10
    """integration steps at evaluation (any K >= 1; bcbench eval --steps overrides)"""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.time_beta = tuple(self.time_beta)
        if self.sampler not in INTEGRATORS or self.sampling_steps < 1:
            raise BCBenchError(f"sampler must be one of {', '.join(INTEGRATORS)} with sampling_steps >= 1")
        if min(self.time_beta) <= 0:
            raise BCBenchError(f"time_beta parameters must be > 0, got {self.time_beta}")

    @classmethod
    def preset(cls, name: str) -> FlowConfig:
        """Every profile of diffusion (quick, cpu, paper): its network sizes and optimiser, flow objective."""
        if "_" in name:
            raise BCBenchError(f"unknown preset '{name}' for flow (quick, cpu or paper; it has no beta schedule)")
        dp = DiffusionConfig.preset(name)
        shared = {f.name: getattr(dp, f.name) for f in dataclasses.fields(cls) if hasattr(dp, f.name)
                  and f.name not in ("sampler", "sampling_steps")}
        return cls(**shared)


class FlowPolicy(DenoiserPolicy):
    name = "flow"
    samplers = INTEGRATORS

    def __init__(self, config: FlowConfig, task: Task | None = None) -> None:
        super().__init__(config, task)
        self.set_sampler(config.sampler, config.sampling_steps)

    def set_sampler(self, kind: str, steps: int, spacing: str | None = None) -> None:
        """Choose the integrator and its number of steps for inference (no retraining)."""
        if kind not in INTEGRATORS or steps < 1:
            raise BCBenchError(f"flow samples with {' or '.join(INTEGRATORS)} and steps >= 1, got {kind} {steps}")
        if spacing is not None:
            raise BCBenchError("--spacing applies to diffusion's timesteps, not to flow's uniform integration steps")
        self.sampler_kind, self.sampler_steps, self.sampler_spacing = kind, steps, None

    def velocity(self, x: torch.Tensor, t: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """v(x_t, t): x (B, Tp, A), t (B,) in [0, 1]."""
        return self.unet(x, t * TIME_SCALE, cond)

    def compute_loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        cond = self.encode(batch["image"], batch["agent_pos"])
        action = batch["action"]  # (B, Tp, A) in [-1, 1]
        noise = self.train_draw(batch, torch.randn, tuple(action.shape[1:]))
        a, b = self.config.time_beta
        if b == 1.0:  # Beta(a, 1) by inversion, u^(1/a): drawn per row like the noise
            s = self.train_draw(batch, torch.rand) ** (1.0 / a)
        else:
            s = torch.distributions.Beta(torch.tensor(a), torch.tensor(b)).sample((action.shape[0],)).to(action.device)
        t = (1.0 - s).clamp(0.0, 1.0)  # (B,)
        x_t = (1 - t)[:, None, None] * noise + t[:, None, None] * action
        if not self.delay_conditioned:
            return F.mse_loss(self.velocity(x_t, t, cond), action - noise)
        # training-time RTC: the prefix at flow time 1 (the clean actions), left out of the loss; drawn after the
        # noise and times, so those are what an unconditioned run draws
        prefix = train_prefix(self, batch, self.config.delay_train, self.config.obs_horizon - 1)
        return masked_mse(self.velocity(prefix.network_input(x_t), t, cond), action - noise, prefix.mask)

    def predict_action_chunk(self, obs: dict[str, torch.Tensor], guide: Guide | None = None,
                             prefix: Prefix | None = None) -> torch.Tensor:
        """Integrate from noise; with `guide`, every velocity is Real-Time Chunking's guided one (policies.guidance);
        with `prefix` (a delay-conditioned network only), its actions are given clean at every step
        (policies.prefix)."""
        self.check_prefix(prefix)
        h = 1.0 / self.sampler_steps
        starts = [i * h for i in range(self.sampler_steps)]
        times = starts + ([t + 0.5 * h for t in starts] if self.sampler_kind == "midpoint" else [])
        model, b, device = self.denoiser(obs, [t * TIME_SCALE for t in times])  # the observation encoded once
        model = self.prefixed(model, prefix)

        def v(x: torch.Tensor, t: float) -> torch.Tensor:
            if guide is None:
                return model(x, t * TIME_SCALE)
            return guided_velocity(lambda x_in: model(x_in, t * TIME_SCALE), x, t, guide)

        x = self.randn(obs, (b, self.config.pred_horizon, self.action_dim), device)  # (B, Tp, A) noise at t = 0
        for t in starts:
            vel = v(x, t)
            if self.sampler_kind == "midpoint":
                vel = v(x + 0.5 * h * vel, t + 0.5 * h)
            x = x + h * vel
        x = x.clamp(-1.0, 1.0)
        return x if prefix is None else prefix.impose(x)  # the prefix is what executes: returned as given
