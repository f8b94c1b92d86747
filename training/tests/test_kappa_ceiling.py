"""The κ the labels allow (kappa_ceiling): the ML estimator against samples of known κ, the PS mean
angle against Monte Carlo, and the report on the analytic box scenes (every neighbour set one
baseline: κ* at the cap everywhere)."""

import math

import pytest
import torch

from psgrasp_training import kappa_ceiling as kc
from psgrasp_training import power_spherical as ps


@pytest.mark.parametrize("kappa", [10.0, 25.0, 60.0])
def test_ml_kappa_recovers_the_concentration_of_samples(kappa):
    mu = torch.tensor([0.2, -0.6, 0.77], dtype=torch.float64)
    mu = mu / mu.norm()
    x = ps.PowerSpherical(mu, torch.tensor(kappa, dtype=torch.float64)).rsample(
        (40000,), generator=torch.Generator().manual_seed(1))
    # With the true direction and with the estimated one (a 40 000-sample mean: within 0.3°).
    assert kc.ml_kappa(x, mu) == pytest.approx(kappa, rel=0.03)
    assert kc.ml_kappa(x) == pytest.approx(kappa, rel=0.03)
    assert float(kc.ml_direction(x) @ mu) > math.cos(math.radians(1.0))


def test_ml_kappa_of_one_or_identical_baselines_is_unbounded_and_of_opposite_ones_below_floor():
    b = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    assert math.isinf(kc.ml_kappa(b))
    assert math.isinf(kc.ml_kappa(b.repeat(5, 1)))
    # Two baselines 60° apart: mean ln(1 + cos 30°) = ln 1.866 → κ* = 1/(ln 2 − ln 1.866) − 1 ≈ 13.5.
    s = math.sin(math.radians(30))
    c = math.cos(math.radians(30))
    two = torch.tensor([[c, s, 0.0], [c, -s, 0.0]], dtype=torch.float64)
    assert kc.ml_kappa(two) == pytest.approx(1 / (math.log(2) - math.log(1 + c)) - 1, rel=1e-9)
    assert kc.ml_kappa(two) < 25


@pytest.mark.parametrize("kappa", [25.0, 100.0])
def test_mean_angle_matches_monte_carlo(kappa):
    mu = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    x = ps.PowerSpherical(mu, torch.tensor(kappa, dtype=torch.float64)).rsample(
        (100000,), generator=torch.Generator().manual_seed(2))
    mc = float(torch.rad2deg(torch.arccos((x @ mu).clamp(-1, 1))).mean())
    assert kc.mean_angle_deg(kappa) == pytest.approx(mc, abs=0.1)
    assert kc.mean_angle_deg(25.0) > kc.mean_angle_deg(50.0) > kc.mean_angle_deg(100.0)


def test_report_on_box_scenes_puts_every_point_at_the_cap(box_dataset, tiny_cfg):
    # Each box face's labels all carry the face's baseline (±x), and 3 mm neighbourhoods never reach
    # the opposite face, so the best direction fits every neighbour exactly.
    lines = []
    r = kc.kappa_ceiling_report(tiny_cfg(), box_dataset, scenes=3, log=lines.append)
    assert r.points > 50
    assert r.at_cap_share == 1.0 and r.below_floor_share == 0.0
    assert r.clamped_mean == pytest.approx(100.0)
    assert r.mean_angle_deg == pytest.approx(0.0, abs=1e-3)
    assert r.mean_neighbours > 1
    # The box labels all have quality 1 (synthetic.py).
    assert r.labels > 0 and r.label_mean_quality == pytest.approx(1.0)
    assert len(lines) == 3 and "κ*" in lines[1] and "quality 1.000" in lines[0]


def test_earned_kappa_per_row_matches_ml_kappa_with_that_nu_and_ignores_padding():
    g = torch.Generator().manual_seed(3)
    nu = torch.nn.functional.normalize(torch.randn(4, 3, generator=g, dtype=torch.float64), dim=1)
    b = torch.nn.functional.normalize(nu.unsqueeze(1) + 0.3 * torch.randn(4, 6, 3, generator=g, dtype=torch.float64), dim=2)
    valid = torch.tensor([[True] * 6, [True] * 3 + [False] * 3, [True] + [False] * 5, [True] * 2 + [False] * 4])
    # Padding rows hold garbage (an antipodal vector) that must not count.
    b[~valid] = -nu.unsqueeze(1).expand(-1, 6, -1)[~valid]
    dot = (b * nu.unsqueeze(1)).sum(-1)
    e = kc.earned_kappa(dot, valid)
    for i in range(4):
        assert float(e[i]) == pytest.approx(kc.ml_kappa(b[i][valid[i]], nu[i]), rel=1e-9)
    # A single neighbour exactly on ν earns an unbounded κ.
    assert math.isinf(float(kc.earned_kappa(torch.ones(1, 1, dtype=torch.float64), torch.ones(1, 1, dtype=torch.bool))[0]))


def test_spearman_of_monotone_reversed_and_constant_inputs():
    from psgrasp_training.train import spearman

    a = torch.tensor([1.0, 5.0, 2.0, 9.0, 3.0])
    assert spearman(a, a ** 3) == pytest.approx(1.0)
    assert spearman(a, -a) == pytest.approx(-1.0)
    assert spearman(a, torch.full_like(a, 25.0)) == 0.0
    # Infinite earned κ (a neighbour exactly on ν) ranks highest.
    assert spearman(a, torch.tensor([1.0, math.inf, 2.0, math.inf, 3.0])) > 0.9
