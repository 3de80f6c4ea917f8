"""DDPM and DDIM sampling for any number of steps, with coefficients precomputed once.

Training uses DDPM's noise levels (Ho et al., 2020) over 100 steps, computed as diffusers' `DDPMScheduler`
computes them (`NoiseSchedule`; equal bit for bit, tested) without importing diffusers, whose import costs seconds
(it imports torch's compiler stack) in every process that builds a Diffusion Policy. At evaluation any K in 1..100
works without retraining: DDPM (ancestral sampling over K of the 100 timesteps, as diffusers' DDPM does
for K < 100) or DDIM (Song et al., 2021; deterministic, eta = 0).

Timestep spacing (Lin et al., 2024, "Common diffusion noise schedules and sample steps are flawed",
Table 2) decides which K timesteps are visited:
- `trailing` (bcbench's default): round(arange(100, 0, -100/K)) - 1. The first timestep is always 99,
  so every K starts from pure noise, and the last step lands on the clean sample.
- `leading` (diffusers' and the study's default): arange(K) * (100 // K), reversed. The first timestep is
  (K - 1) * (100 // K): for K = 1 that is t = 0, so DDIM-1 returns clipped noise, and K = 40 starts at
  t = 78 (sqrt(alpha_bar) = 0.32), i.e. from a half-denoised state that was never sampled.
Both are diffusers' own formulas (except that diffusers' trailing spacing gives K + 1 timesteps, the last
t = -1, for K in {29, 31, 58, 62, 97}; bcbench keeps the first K): DDPM steps to the next timestep of the
list, DDIM to t - 100 // K (as diffusers does; with trailing spacing and K not dividing 100 this is within
one timestep of the next one).
bcbench evaluates them from per-step constants instead of calling `scheduler.step` each time; tests check
the timesteps equal diffusers' for every K and spacing, and the two loops agree to 1e-5 given the same noise.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from bcbench.errors import BCBenchError
from bcbench.utils.system import require_known_version

SPACINGS = ("trailing", "leading")
DEFAULT_SPACING = "trailing"

# Draws standard normal noise of a given shape (per-episode streams live behind it; see BCPolicy.randn).
NoiseFn = Callable[[tuple[int, ...]], torch.Tensor]


@dataclass(frozen=True)
class NoiseSchedule:
    """DDPM's forward-process noise levels (Ho et al. 2020, eq. 4: q(x_t | x_0) = N(sqrt(abar_t) x_0, (1 - abar_t) I)).

    `squaredcos_cap_v2` is Nichol & Dhariwal 2021's cosine schedule (eq. 17, betas capped at 0.999), `linear` Ho
    et al.'s 1e-4..0.02; both in float32, in diffusers' order of operations: equal to diffusers' bit for bit."""

    num_train_timesteps: int
    beta_schedule: str
    betas: torch.Tensor  # (n,) float32
    alphas_cumprod: torch.Tensor  # (n,) float32: abar_t = prod_{s <= t} (1 - beta_s)


def _cosine_alpha_bar(t: float) -> float:
    return math.cos((t + 0.008) / 1.008 * math.pi / 2) ** 2


def make_train_scheduler(num_train_timesteps: int, beta_schedule: str) -> NoiseSchedule:
    """A Diffusion Policy's training noise schedule (the name is from when this built diffusers' scheduler)."""
    n = num_train_timesteps
    if beta_schedule == "squaredcos_cap_v2":  # in float64 Python, then float32, as diffusers' betas_for_alpha_bar
        betas = torch.tensor([min(1 - _cosine_alpha_bar((i + 1) / n) / _cosine_alpha_bar(i / n), 0.999)
                              for i in range(n)], dtype=torch.float32)
    elif beta_schedule == "linear":
        betas = torch.linspace(0.0001, 0.02, n, dtype=torch.float32)
    else:
        raise BCBenchError(f"beta_schedule must be squaredcos_cap_v2 or linear, got '{beta_schedule}'")
    return NoiseSchedule(n, beta_schedule, betas, torch.cumprod(1.0 - betas, dim=0))


def spaced_timesteps(n: int, steps: int, spacing: str) -> list[int]:
    """The K = `steps` of n timesteps visited, first (noisiest) first: diffusers' formulas for DDPM and DDIM alike
    (`set_timesteps`, steps_offset 0), and for trailing spacing its first K only (see the module's docstring)."""
    if check_spacing(spacing) == "leading":
        ts = (np.arange(0, steps) * (n // steps)).round()[::-1].astype(np.int64)
    else:
        ts = np.round(np.arange(n, 0, -(n / steps))).astype(np.int64) - 1
    return [int(t) for t in ts[:steps]]


def check_spacing(spacing: str) -> str:
    if spacing not in SPACINGS:
        raise BCBenchError(f"timestep spacing must be one of {', '.join(SPACINGS)}, got '{spacing}'")
    return spacing


def make_diffusers_sampler(schedule: NoiseSchedule, kind: str, steps: int, spacing: str = DEFAULT_SPACING):
    """diffusers' scheduler for sampling (the public code's way, the tests' reference), timesteps set for `steps` and
    `spacing`, over the same training schedule."""
    from diffusers import DDIMScheduler, DDPMScheduler  # seconds to import: only where the reference is asked for

    require_known_version("diffusers")
    train = DDPMScheduler(num_train_timesteps=schedule.num_train_timesteps, beta_schedule=schedule.beta_schedule,
                          clip_sample=True, prediction_type="epsilon", variance_type="fixed_small")
    cls = {"ddpm": DDPMScheduler, "ddim": DDIMScheduler}[kind]
    sched = cls.from_config(train.config, timestep_spacing=check_spacing(spacing))
    sched.set_timesteps(steps)
    # diffusers (0.42.1) builds trailing timesteps with a float arange, which for K in {29, 31, 58, 62, 97}
    # yields K + 1 of them, the last being t = -1 (alphas_cumprod[-1] is the *noisiest* level): keep K.
    sched.timesteps = sched.timesteps[:steps]
    return sched


@dataclass
class SamplerPlan:
    """Per-step constants: x0 = clip((x - a_k eps) * b_k); x <- c_k x0 + d_k (x or eps) + s_k z."""

    kind: str
    spacing: str
    timesteps: list[int]
    a: list[float]
    b: list[float]
    c: list[float]
    d: list[float]
    s: list[float]


def plan(schedule: NoiseSchedule, kind: str, steps: int, spacing: str = DEFAULT_SPACING) -> SamplerPlan:
    """Constants of `kind` sampling with `steps` steps, from the training schedule's alphas."""
    n = schedule.num_train_timesteps
    if kind not in ("ddpm", "ddim"):
        raise BCBenchError(f"sampler must be ddpm or ddim, got '{kind}'")
    if not 1 <= steps <= n:
        raise BCBenchError(f"steps must be in 1..{n}, got {steps}")
    ac = schedule.alphas_cumprod.double()
    one = torch.tensor(1.0, dtype=torch.float64)
    p = SamplerPlan(kind, spacing, spaced_timesteps(n, steps, spacing), [], [], [], [], [])
    for k, t in enumerate(p.timesteps):
        # diffusers' DDPM steps to the next timestep of the list (-1 after the last), its DDIM by a fixed stride
        last = k + 1 == len(p.timesteps)
        prev = (-1 if last else p.timesteps[k + 1]) if kind == "ddpm" else t - n // steps
        a_t = ac[t]
        a_prev = ac[prev] if prev >= 0 else one
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


# Edits the clipped clean estimate x0 (B, Tp, A) at a visited timestep t (Real-Time Chunking's inpainting).
CleanEdit = Callable[[torch.Tensor, int], torch.Tensor]


def run_plan(p: SamplerPlan, denoise, x: torch.Tensor, noise: NoiseFn, edit: CleanEdit | None = None
             ) -> torch.Tensor:
    """Denoise `x` (pure noise) with `denoise(x, t) -> eps`; DDPM's fresh noise comes from `noise(shape)`.

    `edit(x0, t)`, if given, changes the clean estimate after DP's clip and before the step uses it: the one place
    the sampler already edits x0 (bcbench.policies.guidance.inpaint_clean).
    """
    for k, t in enumerate(p.timesteps):
        eps = denoise(x, t)
        x0 = ((x - p.a[k] * eps) * p.b[k]).clamp_(-1.0, 1.0)
        if edit is not None:
            x0 = edit(x0, t)
        if p.kind == "ddpm":
            x = p.c[k] * x0 + p.d[k] * x
            if t > 0:
                x = x + p.s[k] * noise(tuple(x.shape)).to(dtype=x.dtype)
        else:
            x = p.c[k] * x0 + p.d[k] * eps
    return x


def run_diffusers(sched, denoise, x: torch.Tensor, generator=None) -> torch.Tensor:
    """The reference loop: call diffusers' `step` for every timestep (what the public code does).

    `generator` is a torch.Generator or a list of them, one per batch row (diffusers draws row by row then).
    """
    for t in sched.timesteps:
        eps = denoise(x, int(t))
        x = sched.step(eps, t, x, generator=generator).prev_sample
    return x
