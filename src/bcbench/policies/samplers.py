"""DDPM and DDIM sampling for any number of steps, with coefficients precomputed once.

Training uses diffusers' `DDPMScheduler` (Ho et al., 2020) with 100 steps. At evaluation any K in 1..100
works without retraining: DDPM (ancestral sampling over the strided timesteps, as diffusers' DDPM does for
K < 100) or DDIM (Song et al., 2021; deterministic, eta = 0). Both use diffusers' own timestep spacing
("leading") and formulas; `bcbench` evaluates them from per-step constants instead of calling
`scheduler.step` each time, and a test checks the two agree to float tolerance given the same noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from bcbench.errors import BCBenchError


def make_train_scheduler(num_train_timesteps: int, beta_schedule: str):
    from diffusers import DDPMScheduler

    if beta_schedule not in ("squaredcos_cap_v2", "linear"):
        raise BCBenchError(f"beta_schedule must be squaredcos_cap_v2 or linear, got '{beta_schedule}'")
    return DDPMScheduler(num_train_timesteps=num_train_timesteps, beta_schedule=beta_schedule, clip_sample=True,
                         prediction_type="epsilon", variance_type="fixed_small")


def make_diffusers_sampler(train_scheduler, kind: str, steps: int):
    """diffusers' scheduler for sampling (the 'reference' way), timesteps set for `steps`."""
    from diffusers import DDIMScheduler, DDPMScheduler

    cls = {"ddpm": DDPMScheduler, "ddim": DDIMScheduler}[kind]
    sched = cls.from_config(train_scheduler.config)
    sched.set_timesteps(steps)
    return sched


@dataclass
class SamplerPlan:
    """Per-step constants: x0 = clip((x - a_k eps) * b_k); x <- c_k x0 + d_k (x or eps) + s_k z."""

    kind: str
    timesteps: list[int]
    a: list[float]
    b: list[float]
    c: list[float]
    d: list[float]
    s: list[float]


def plan(train_scheduler, kind: str, steps: int) -> SamplerPlan:
    """Constants of `kind` sampling with `steps` steps, from the training scheduler's alphas."""
    n = int(train_scheduler.config.num_train_timesteps)
    if kind not in ("ddpm", "ddim"):
        raise BCBenchError(f"sampler must be ddpm or ddim, got '{kind}'")
    if not 1 <= steps <= n:
        raise BCBenchError(f"steps must be in 1..{n}, got {steps}")
    ref = make_diffusers_sampler(train_scheduler, kind, steps)  # only for its timesteps: one source of truth
    ac = train_scheduler.alphas_cumprod.double()
    ratio = n // steps
    p = SamplerPlan(kind, [int(t) for t in ref.timesteps], [], [], [], [], [])
    for t in p.timesteps:
        prev = t - ratio
        a_t = ac[t]
        a_prev = ac[prev] if prev >= 0 else torch.tensor(1.0, dtype=torch.float64)
        p.a.append(float((1 - a_t).sqrt()))
        p.b.append(float(1 / a_t.sqrt()))
        if kind == "ddpm":
            alpha_t, beta_t = a_t / a_prev, 1 - a_t / a_prev
            p.c.append(float(a_prev.sqrt() * beta_t / (1 - a_t)))  # weight of the predicted x0
            p.d.append(float(alpha_t.sqrt() * (1 - a_prev) / (1 - a_t)))  # weight of the current sample
            var = torch.clamp((1 - a_prev) / (1 - a_t) * beta_t, min=1e-20) if t > 0 else torch.tensor(0.0)
            p.s.append(float(var.sqrt()))
        else:
            p.c.append(float(a_prev.sqrt()))
            p.d.append(float((1 - a_prev).sqrt()))  # weight of the predicted noise (eta = 0)
            p.s.append(0.0)
    return p


def run_plan(p: SamplerPlan, denoise, x: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """Denoise `x` (pure noise) with `denoise(x, t) -> eps`; noise drawn in diffusers' order from generator."""
    for k, t in enumerate(p.timesteps):
        eps = denoise(x, t)
        x0 = ((x - p.a[k] * eps) * p.b[k]).clamp_(-1.0, 1.0)
        if p.kind == "ddpm":
            x = p.c[k] * x0 + p.d[k] * x
            if t > 0:
                z = torch.randn(x.shape, generator=generator, device=x.device, dtype=x.dtype)
                x = x + p.s[k] * z
        else:
            x = p.c[k] * x0 + p.d[k] * eps
    return x


def run_diffusers(sched, denoise, x: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """The reference loop: call diffusers' `step` for every timestep (what the public code does)."""
    for t in sched.timesteps:
        eps = denoise(x, int(t))
        x = sched.step(eps, t, x, generator=generator).prev_sample
    return x
