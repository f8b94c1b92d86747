"""The κ the labels allow: per training point, the maximum-likelihood Power-Spherical concentration
of its neighbour baselines about their best direction (issue 18: "κ visibly above its floor").

The baseline loss is the mean over a point's neighbour labels of −log PS(b_n | ν, κ). For a given ν
it is minimised (d = 3, log C(κ) = ln(κ+1) − (κ+2) ln 2 − ln π) where

    1/(κ* + 1) = ln 2 − mean_n ln(1 + ν·b_n),

so a model that predicted every point's best ν would earn κ* there; a model whose ν is further off
earns less. ``kappa_ceiling_report`` measures κ* over a dataset's training points with the training's
own point rule and neighbour query, before the paper's clamp to [κ0, 4κ0].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from .config import Config
from .data import SceneDataset
from .losses import GraspIndex, contact_voxel_points

_LOG2 = math.log(2.0)


def ml_direction(b: torch.Tensor, valid: torch.Tensor | None = None) -> torch.Tensor:
    """The neighbours' mean direction: b [..., n, 3] → [..., 3] unit (the PS maximum-likelihood
    direction for sets concentrated in a hemisphere, which neighbour baselines of one contact are);
    ``valid`` [..., n] masks padding."""
    if valid is not None:
        b = b * valid.unsqueeze(-1)
    return torch.nn.functional.normalize(b.sum(-2), dim=-1, eps=1e-12)


def ml_kappa(b: torch.Tensor, nu: torch.Tensor | None = None) -> float:
    """Maximum-likelihood κ of unit vectors b [n, 3] under PS(ν, κ) on S² (ν: their mean direction
    unless given); ``inf`` when they all coincide with ν (a single neighbour), 0 (uniform) when they
    lie so far from ν that no κ ≥ 0 does better."""
    nu = ml_direction(b) if nu is None else nu
    dot = b.to(torch.float64) @ nu.to(torch.float64)
    return float(earned_kappa(dot.unsqueeze(0), torch.ones_like(dot, dtype=torch.bool).unsqueeze(0))[0])


def earned_kappa(dot: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Per row, the maximum-likelihood κ of the valid neighbours given a fixed ν: dot [N, k] = ν·b_n,
    valid [N, k] mask (≥ 1 per row). ``inf`` where every neighbour lies on ν. The κ a model with
    this ν earns at each point (before the clamp to [κ0, 4κ0]); ≥ 0 as ``ml_kappa``."""
    lp = torch.log1p(dot.to(torch.float64).clamp(-1.0 + 1e-9, 1.0))
    n = valid.sum(1).clamp_min(1).to(torch.float64)
    g = _LOG2 - torch.where(valid, lp, torch.zeros_like(lp)).sum(1) / n
    return torch.where(g > 1e-12, (1.0 / g.clamp_min(1e-12) - 1.0).clamp_min(0.0), torch.full_like(g, math.inf))


def mean_angle_deg(kappa: float, samples: int = 200_001) -> float:
    """Mean angle to μ under PS(μ, κ) on S², degrees (numerical integration over t = μᵀx, whose
    density on S² is ∝ (1 + t)^κ)."""
    t = torch.linspace(-1.0, 1.0, samples, dtype=torch.float64)
    w = torch.exp(kappa * torch.log1p(t.clamp_min(-1.0 + 1e-15)))
    return float((w * torch.rad2deg(torch.arccos(t))).sum() / w.sum())


@dataclass
class KappaCeiling:
    """κ* over the points with ≥ 1 neighbour label."""

    points: int
    single_neighbour_share: float
    mean_neighbours: float
    #: over points with ≥ 2 neighbours: mean angle of the neighbours to their ML direction, degrees
    mean_angle_deg: float
    median_kappa: float
    below_floor_share: float
    at_cap_share: float
    #: mean of κ* clamped to [κ0, 4κ0] (the paper's mapping), all points with a neighbour
    clamped_mean: float
    #: grasp labels of the scenes read (``kappa_ceiling_report``; 0 from ``kappa_ceiling`` alone)
    labels: int = 0
    #: their mean antipodal quality (NaN without labels)
    label_mean_quality: float = math.nan


def kappa_ceiling(kappas, angles, counts, kappa0: float) -> KappaCeiling:
    """Summary of per-point κ* (``inf`` for single-neighbour points), their mean angles and neighbour
    counts (sequences or 1-D tensors of equal length)."""
    k = torch.as_tensor(kappas, dtype=torch.float64)
    n = torch.as_tensor(counts, dtype=torch.float64)
    multi = n > 1
    km = k[multi]
    clamped = k.clamp(kappa0, 4 * kappa0)
    nan = math.nan
    return KappaCeiling(
        points=len(kappas),
        single_neighbour_share=float((n == 1).double().mean()) if len(n) else nan,
        mean_neighbours=float(n.mean()) if len(n) else nan,
        mean_angle_deg=float(torch.as_tensor(angles, dtype=torch.float64)[multi].mean()) if bool(multi.any()) else nan,
        median_kappa=float(km.median()) if len(km) else nan,
        below_floor_share=float((k < kappa0).double().mean()) if len(k) else nan,
        at_cap_share=float((k >= 4 * kappa0).double().mean()) if len(k) else nan,
        clamped_mean=float(clamped.mean()) if len(k) else nan,
    )


def kappa_ceiling_report(cfg: Config, data: Path, scenes: int, log=print) -> KappaCeiling:
    """κ* of the training points (the config's contact-point rule and neighbour query) of the first
    ``scenes`` scenes of the dataset's training split."""
    from .train import derive_seed

    ds = SceneDataset(data, cfg)
    kappas: list[torch.Tensor] = []
    angles: list[torch.Tensor] = []
    counts: list[torch.Tensor] = []
    labels, quality_sum = 0, 0.0
    c = cfg.contacts
    for e in ds.train_entries[:scenes]:
        scene = ds.scene(e)
        labels += len(scene.quality)
        quality_sum += float(scene.quality.to(torch.float64).sum())
        g = torch.Generator().manual_seed(derive_seed(cfg.seed, 5, scene.index))
        pts = contact_voxel_points(scene, cfg, g)
        idx = GraspIndex(scene.contact, max(c.neighbour_radius_m, scene.voxel_size_m)).query(
            pts, c.neighbour_radius_m, c.max_neighbours).idx
        idx = idx[(idx >= 0).any(1)]
        valid = idx >= 0
        b = scene.baseline[idx.clamp(min=0)].to(torch.float64)  # [N, k, 3]
        nu = ml_direction(b, valid)
        dot = (b * nu.unsqueeze(1)).sum(-1)
        n = valid.sum(1)
        kappas.append(earned_kappa(dot, valid))
        ang = torch.rad2deg(torch.arccos(dot.clamp(-1.0, 1.0)))
        angles.append(torch.where(valid, ang, torch.zeros_like(ang)).sum(1) / n)
        counts.append(n)
    cat = (lambda xs: torch.cat(xs) if xs else torch.zeros(0, dtype=torch.float64))
    kappas, angles, counts = cat(kappas), cat(angles), cat(counts)
    k0 = cfg.model.kappa0
    r = kappa_ceiling(kappas, angles, counts, k0)
    r = replace(r, labels=labels, label_mean_quality=quality_sum / labels if labels else math.nan)
    log(f"{min(scenes, len(ds.train_entries))} scenes, {r.labels} grasp labels (mean antipodal quality "
        f"{r.label_mean_quality:.3f}), {r.points} training points with a neighbour label "
        f"(mean {r.mean_neighbours:.1f} neighbours, {100 * r.single_neighbour_share:.0f} % a single one)")
    log(f"κ* (the best a model can earn per point): median {r.median_kappa:.1f} over points with ≥ 2 neighbours "
        f"(their mean angle to the best direction {r.mean_angle_deg:.1f}°); below κ0 = {k0:g}: "
        f"{100 * r.below_floor_share:.0f} %, at the cap {4 * k0:g}: {100 * r.at_cap_share:.0f} %; "
        f"clamped to [κ0, 4κ0] mean {r.clamped_mean:.1f}")
    log("mean angle to ν under PS(ν, κ): " + ", ".join(f"κ {k:g}: {mean_angle_deg(k):.1f}°" for k in (k0, 2 * k0, 4 * k0)))
    return r
