"""Real-Time Chunking's guided inpainting (Black, Galliker, Levine 2025, "Real-Time Execution of Action Chunking
Flow Policies"), inside the sampling loop of flow matching and Diffusion Policy.

The controller gives the chunk that is executing, aligned to the new chunk's indices (`target`, normalised),
and a soft mask `weights` W over them (bcbench.evaluation.strategies.prefix_weights, the paper's eq. 5): 1 on
the frozen prefix (actions that execute before the new chunk arrives), decaying over the rest of the overlap,
0 where the old chunk has no action. At every network evaluation the velocity is corrected towards the target
with the pseudo-inverse guidance of PiGDM (Song et al. 2023) that the paper uses (its eq. 2-4):

    A1_hat = A_tau + (1 - tau) v(A_tau, o, tau)                    the clean-chunk estimate
    g      = (target - A1_hat)^T diag(W) dA1_hat / dA_tau           a vector-Jacobian product (one backward pass)
    v'     = v + min(beta, (1 - tau) / tau * 1 / r_tau^2) g,  r_tau^2 = (1 - tau)^2 / (tau^2 + (1 - tau)^2)

(tau = 0 is noise, 1 the data, as in bcbench's flow). The weight's clip beta is the paper's Sec. 4.2 choice
(default 5). The vector-Jacobian product needs autograd through the U-Net: flow's guidance runs under the torch
modes only, not in an exported OpenVINO or ONNX Runtime graph (which computes forward passes only).

`jacobian=False` (`--rtc-no-jacobian`) takes the same pseudo-inverse step with J = I, as Diffusion Policy always
does (below): the clean estimate moves towards the target by f = min(1, (1 - tau) w(tau)) on the mask, and the
velocity is the one that lands there, v' = v + f / (1 - tau) diag(W) (target - A1_hat). Not the paper's method
(an extension: no backward pass, naive's cost, every backend); the record names it.

Diffusion Policy (epsilon prediction) is carried over without the Jacobian, in its clean estimate. Its state
x_t / (sqrt(abar) + sqrt(1 - abar)) is a rectified-flow state at tau = sqrt(abar) / (sqrt(abar) + sqrt(1 - abar))
with the same clean estimate x0, so flow's correction moves that estimate by (1 - tau) w(tau) J J^T diag(W) e to
first order (J = d x0 / d state). For epsilon prediction J = (I - sqrt(1 - abar) d eps / dx) (1 + sqrt(1 - abar)
/ sqrt(abar)): a small residual of the network times 1 / sqrt(abar), which is 2,000 at the noisiest step of the
100-step squared-cosine schedule. The network's x0 there is barely trained (the epsilon loss weighs an x0 error
by abar / (1 - abar)), so its Jacobian is noise times 2,000, and the guided step saturated DP's chunks
(results/strategies-dp-b: 0.22 in sync against naive's 0.83). bcbench therefore takes PiGDM's pseudo-inverse step
with J = I: the clipped clean estimate moves towards the target by the fraction flow's rule would move it,

    x0' = x0 + f(tau) diag(W) (target - x0),   f(tau) = min(1, (1 - tau) w(tau))   (at most all the way: no
                                                                                    overshoot without a Jacobian)

where DP's sampler already edits x0 (its clip to [-1, 1]), before the DDPM / DDIM step uses it. No backward pass:
it costs what naive costs and runs under every backend. beta = 0 is naive; W = 1 on the frozen prefix.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch


@dataclass
class Guide:
    """What the new chunk is inpainted towards: target (B, Tp, A) normalised, weights (B, Tp) in [0, 1]."""

    target: torch.Tensor
    weights: torch.Tensor
    max_guidance: float  # beta
    jacobian: bool = True  # flow: through the network's Jacobian (the paper); False: J = I (module docstring)

    def repeat(self, n: int) -> Guide:
        """The same guide for n candidates of every row (rows repeated in place: r0, r0, ..., r1, ...)."""
        return Guide(self.target.repeat_interleave(n, 0), self.weights.repeat_interleave(n, 0), self.max_guidance,
                     self.jacobian)


def clean_fraction(tau: float, max_guidance: float) -> float:
    """How far a J = I step moves the clean estimate towards the target: min(1, (1 - tau) w(tau))."""
    return min(1.0, (1 - tau) * guidance_weight(tau, max_guidance))


def guidance_weight(tau: float, max_guidance: float) -> float:
    """min(beta, (1 - tau) / tau / r_tau^2) (the paper's eq. 4, with its clip); beta at tau = 0 or 1."""
    if tau <= 0.0 or tau >= 1.0:
        return max_guidance
    return min(max_guidance, (tau ** 2 + (1 - tau) ** 2) / (tau * (1 - tau)))


def correction(clean: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]], x: torch.Tensor, guide: Guide
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """(the network's output at x, g = (target - clean)^T diag(W) d clean / dx), one forward and one backward pass.

    `clean(x)` returns (network output, clean-chunk estimate). The error is a constant of the product (PiGDM).
    """
    with torch.enable_grad():  # the runner samples guided chunks under no_grad, not inference mode
        x_in = x.detach().clone().requires_grad_(True)
        out, estimate = clean(x_in)
        error = (guide.target - estimate.detach()) * guide.weights[..., None]  # (B, Tp, A)
        (g,) = torch.autograd.grad(estimate, x_in, grad_outputs=error)
    return out.detach(), g


def guided_velocity(velocity: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor, tau: float, guide: Guide
                    ) -> torch.Tensor:
    """Flow: v'(x, tau) = v + w(tau) g, with the clean estimate x + (1 - tau) v; J = I: the velocity that moves that
    estimate by clean_fraction of the way to the target."""
    w = guidance_weight(tau, guide.max_guidance)
    if w == 0.0:
        return velocity(x)  # no guidance: exactly the unguided step (and no backward pass)
    if not guide.jacobian:
        v = velocity(x)
        error = guide.weights[..., None] * (guide.target - (x + (1 - tau) * v))  # (B, Tp, A)
        return v + clean_fraction(tau, guide.max_guidance) / (1 - tau) * error

    def clean(x_in: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        v = velocity(x_in)
        return v, x_in + (1 - tau) * v

    v, g = correction(clean, x, guide)
    return v + w * g


def inpaint_clean(x0: torch.Tensor, alpha_bar: float, guide: Guide) -> torch.Tensor:
    """Diffusion Policy: x0 + f(tau) W (target - x0), tau the flow time of the state (module docstring)."""
    a, s = math.sqrt(alpha_bar), math.sqrt(1 - alpha_bar)
    f = clean_fraction(a / (a + s), guide.max_guidance)
    if f == 0.0:
        return x0  # no guidance: exactly the unguided step
    return x0 + f * guide.weights[..., None] * (guide.target - x0)  # (B, Tp, A)
