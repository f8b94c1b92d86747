import math

import pytest
import torch
from power_spherical import PowerSpherical as ReferencePS

from psgrasp_training import power_spherical as ps


def sphere_grid(n_theta=400, n_phi=800):
    """Midpoint quadrature nodes and weights on S² (z = cos θ)."""
    th = (torch.arange(n_theta, dtype=torch.float64) + 0.5) * math.pi / n_theta
    ph = (torch.arange(n_phi, dtype=torch.float64) + 0.5) * 2 * math.pi / n_phi
    t, p = torch.meshgrid(th, ph, indexing="ij")
    x = torch.stack([torch.sin(t) * torch.cos(p), torch.sin(t) * torch.sin(p), torch.cos(t)], -1).reshape(-1, 3)
    w = (torch.sin(t) * (math.pi / n_theta) * (2 * math.pi / n_phi)).reshape(-1)
    return x, w


@pytest.mark.parametrize("kappa", [0.0, 1.0, 10.0, 25.0, 100.0])
def test_density_integrates_to_one(kappa):
    x, w = sphere_grid()
    mu = torch.tensor([0.3, -0.5, 0.81], dtype=torch.float64)
    mu = mu / mu.norm()
    p = ps.log_prob(x, mu, torch.tensor(kappa, dtype=torch.float64)).exp()
    assert abs(float((p * w).sum()) - 1.0) < 2e-3


def test_log_normalizer_closed_form():
    # d = 3: C(κ) = (κ+1) / (2^(κ+2) π); κ = 0 is the uniform density 1/(4π).
    assert abs(float(ps.log_normalizer(torch.tensor(0.0))) - math.log(1 / (4 * math.pi))) < 1e-6
    k = torch.tensor(25.0, dtype=torch.float64)
    assert abs(float(ps.log_normalizer(k)) - math.log(26 / (2**27 * math.pi))) < 1e-9


def test_matches_reference_package():
    g = torch.Generator().manual_seed(0)
    mu = torch.randn(64, 3, generator=g, dtype=torch.float64)
    mu = mu / mu.norm(dim=1, keepdim=True)
    x = torch.randn(64, 3, generator=g, dtype=torch.float64)
    x = x / x.norm(dim=1, keepdim=True)
    kappa = torch.rand(64, generator=g, dtype=torch.float64) * 100
    ref = ReferencePS(mu, kappa).log_prob(x)
    ours = ps.log_prob(x, mu, kappa)
    assert torch.allclose(ours, ref, atol=1e-6)


def test_rsample_moments_and_determinism():
    mu = torch.tensor([[0.0, 0.6, -0.8]], dtype=torch.float64)
    kappa = torch.tensor([20.0], dtype=torch.float64)
    d = ps.PowerSpherical(mu, kappa)
    s1 = d.rsample((20000,), generator=torch.Generator().manual_seed(5))
    s2 = d.rsample((20000,), generator=torch.Generator().manual_seed(5))
    assert torch.equal(s1, s2)
    assert torch.allclose(s1.norm(dim=-1), torch.ones(1, dtype=torch.float64), atol=1e-9)
    # E[x] = μ κ/(κ+2) = 0.909 μ; Monte Carlo error ~ 0.002.
    assert torch.allclose(s1.mean(0), d.mean, atol=0.01)
    # Same marginal of μᵀx as the reference package (means of t within MC error).
    ref = ReferencePS(mu[0], kappa[0]).rsample((20000,))
    assert abs(float((ref @ mu[0]).mean()) - float((s1[:, 0] @ mu[0]).mean())) < 0.01


def test_antipode_is_finite():
    mu = torch.tensor([0.0, 0.0, 1.0])
    lp = ps.log_prob(-mu, mu, torch.tensor(50.0))
    assert torch.isfinite(lp) and lp < -500
