"""Power-Spherical distribution PS(μ, κ) on the unit sphere S² (De Cao & Aziz 2020), d = 3.

Density: p(x | μ, κ) = C(κ) (1 + μᵀx)^κ with
log C(κ) = ln(κ+1) − (κ+2) ln 2 − ln π   (d = 3: α = κ + 1, β = 1).
"""

from __future__ import annotations

import math

import torch

_LOG2 = math.log(2.0)
_LOGPI = math.log(math.pi)


def log_normalizer(kappa: torch.Tensor) -> torch.Tensor:
    """log C(κ) for d = 3."""
    return torch.log1p(kappa) - (kappa + 2.0) * _LOG2 - _LOGPI


#: μᵀx is clamped to [−1 + DOT_FLOOR, 1] so that antipodal points give a finite (very low) density.
DOT_FLOOR = 1e-6


def log_prob_from_dot(dot: torch.Tensor, kappa: torch.Tensor) -> torch.Tensor:
    """log p as a function of μᵀx (broadcast with κ)."""
    return log_normalizer(kappa) + kappa * torch.log1p(dot.clamp(-1.0 + DOT_FLOOR, 1.0))


def log_prob(x: torch.Tensor, mu: torch.Tensor, kappa: torch.Tensor) -> torch.Tensor:
    """log p(x | μ, κ); x, μ: [..., 3] unit vectors, κ: [...] (broadcast)."""
    return log_prob_from_dot((mu * x).sum(-1), kappa)


class PowerSpherical:
    """PS(μ, κ) on S² with reparameterised sampling."""

    def __init__(self, mu: torch.Tensor, kappa: torch.Tensor):
        if mu.shape[-1] != 3:
            raise ValueError(f"mu must have a last dimension of 3, got {tuple(mu.shape)}")
        self.mu = mu
        self.kappa = torch.as_tensor(kappa, dtype=mu.dtype, device=mu.device).expand(mu.shape[:-1])

    def log_prob(self, x: torch.Tensor) -> torch.Tensor:
        """log density at unit vectors x [..., 3]."""
        return log_prob(x, self.mu, self.kappa)

    @property
    def mean(self) -> torch.Tensor:
        """E[x] = μ · κ/(κ + 2) for d = 3 (E[t] = (α−β)/(α+β), α = κ+1, β = 1)."""
        return self.mu * (self.kappa / (self.kappa + 2.0)).unsqueeze(-1)

    def rsample(self, sample_shape: torch.Size | tuple = (), generator: torch.Generator | None = None) -> torch.Tensor:
        """Reparameterised samples [*sample_shape, *batch, 3].

        t = 2U^(1/(1+κ)) − 1 is the marginal of μᵀx for d = 3 (Beta(κ+1, 1) mapped to [−1, 1]);
        a uniform tangent direction v completes y = (t, √(1−t²) v) in the frame where μ = e1, and a
        Householder reflection maps e1 to μ.
        """
        shape = torch.Size(sample_shape) + self.mu.shape[:-1]
        dtype, device = self.mu.dtype, self.mu.device
        u = torch.rand(shape, dtype=dtype, device=device, generator=generator)
        # U^(1/(κ+1)) = exp(log U / (κ+1)); clamp keeps log finite.
        t = 2.0 * torch.exp(torch.log(u.clamp_min(1e-30)) / (self.kappa + 1.0)) - 1.0
        phi = 2.0 * math.pi * torch.rand(shape, dtype=dtype, device=device, generator=generator)
        r = torch.sqrt((1.0 - t * t).clamp_min(0.0))
        y = torch.stack([t, r * torch.cos(phi), r * torch.sin(phi)], dim=-1)
        e1 = torch.zeros_like(self.mu)
        e1[..., 0] = 1.0
        u_vec = e1 - self.mu
        norm = u_vec.norm(dim=-1, keepdim=True)
        # μ = e1: the reflection is the identity.
        u_vec = torch.where(norm > 1e-7, u_vec / norm.clamp_min(1e-7), torch.zeros_like(u_vec))
        return y - 2.0 * (y * u_vec).sum(-1, keepdim=True) * u_vec
