"""Losses of the paper: focal label loss and the grasp loss (baseline, approach, width, quality,
collision) on sampled contact points labelled by their neighbour grasps.

Neighbours of a point: up to ``max_neighbours`` nearest true grasp contacts within
``neighbour_radius_m``, found by voxel hashing (cell = radius, 27 adjacent cells searched).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
from torch.nn import functional as F

from . import power_spherical as ps
from .config import Config
from .data import Scene
from .decode import approach_vectors, sample_grid
from .model import N_APPROACHES


def focal_loss(logits: torch.Tensor, labels: torch.Tensor, class_weights: torch.Tensor | list[float],
               gamma: float) -> torch.Tensor:
    """Class-weighted multi-class focal loss Σ −α_y (1 − p_y)^γ log p_y / Σ α_y.

    logits [B, C, ...], labels [B, ...] (or [...] for B = 1). At γ = 0 this equals
    ``F.cross_entropy(logits, labels, weight=class_weights)``.
    """
    if labels.dim() == logits.dim() - 1 and labels.shape[0] != logits.shape[0]:
        labels = labels.unsqueeze(0)
    if labels.dim() == logits.dim() - 2:
        labels = labels.unsqueeze(0)
    w = torch.as_tensor(class_weights, dtype=logits.dtype, device=logits.device)
    logp = F.log_softmax(logits, dim=1)
    lp_y = logp.gather(1, labels.unsqueeze(1)).squeeze(1)
    alpha = w[labels]
    mod = (1.0 - lp_y.exp()).clamp_min(0.0).pow(gamma) if gamma > 0 else torch.ones_like(lp_y)
    return -(alpha * mod * lp_y).sum() / alpha.sum().clamp_min(1e-12)


class GraspIndex:
    """Voxel hash of grasp contacts for fixed-radius neighbour queries (no KD-tree)."""

    def __init__(self, contacts: torch.Tensor, cell_m: float):
        self.cell = float(cell_m)
        self.contacts = contacts
        cells = torch.floor(contacts.to(torch.float64) / self.cell).to(torch.int64)
        self.origin = cells.min(dim=0).values - 1 if len(contacts) else torch.zeros(3, dtype=torch.int64)
        self.size = (cells.max(dim=0).values - self.origin + 2) if len(contacts) else torch.ones(3, dtype=torch.int64)
        keys = self._keys(cells)
        self.sorted_keys, self.order = torch.sort(keys, stable=True)

    def _keys(self, cells: torch.Tensor) -> torch.Tensor:
        c = (cells - self.origin).clamp(min=0)
        c = torch.minimum(c, self.size - 1)
        return (c[..., 0] * self.size[1] + c[..., 1]) * self.size[2] + c[..., 2]

    def query(self, points: torch.Tensor, radius_m: float, max_neighbours: int) -> "Neighbours":
        """Up to max_neighbours nearest contacts within radius_m of each point (radius ≤ cell)."""
        n = points.shape[0]
        k = max_neighbours
        idx = torch.full((n, k), -1, dtype=torch.int64)
        dist = torch.full((n, k), math.inf, dtype=torch.float32)
        if n == 0 or len(self.contacts) == 0:
            return Neighbours(idx, dist)
        if radius_m > self.cell + 1e-12:
            raise ValueError(f"query radius {radius_m} exceeds the hash cell {self.cell}")
        pc = torch.floor(points.detach().to(torch.float64) / self.cell).to(torch.int64)
        off = torch.tensor([[dx, dy, dz] for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)])
        cells = pc.unsqueeze(1) + off.unsqueeze(0)  # [n, 27, 3]
        inside = ((cells - self.origin >= 0) & (cells - self.origin < self.size)).all(-1)
        keys = self._keys(cells)
        start = torch.searchsorted(self.sorted_keys, keys, right=False)
        end = torch.searchsorted(self.sorted_keys, keys, right=True)
        counts = torch.where(inside, end - start, torch.zeros_like(start)).reshape(-1)
        total = int(counts.sum())
        if total == 0:
            return Neighbours(idx, dist)
        pair = torch.repeat_interleave(torch.arange(n * 27), counts)
        first = torch.cumsum(counts, 0) - counts
        offset = torch.arange(total) - first[pair]
        cand = self.order[start.reshape(-1)[pair] + offset]
        q = pair // 27
        d = (points.detach()[q] - self.contacts[cand]).norm(dim=1)
        keep = d <= radius_m
        q, cand, d = q[keep], cand[keep], d[keep]
        if q.numel() == 0:
            return Neighbours(idx, dist)
        # Sort by (query, distance, grasp index) — deterministic.
        o = torch.sort(cand, stable=True).indices
        q, cand, d = q[o], cand[o], d[o]
        o = torch.sort(d, stable=True).indices
        q, cand, d = q[o], cand[o], d[o]
        o = torch.sort(q, stable=True).indices
        q, cand, d = q[o], cand[o], d[o]
        qcount = torch.bincount(q, minlength=n)
        rank = torch.arange(q.numel()) - (torch.cumsum(qcount, 0) - qcount)[q]
        sel = rank < k
        idx[q[sel], rank[sel]] = cand[sel]
        dist[q[sel], rank[sel]] = d[sel].to(torch.float32)
        return Neighbours(idx, dist)


@dataclass
class Neighbours:
    """Neighbour grasps of N points: indices [N, k] (−1 = none, nearest first) and distances."""

    idx: torch.Tensor
    dist: torch.Tensor

    @property
    def valid(self) -> torch.Tensor:
        """[N, k] mask of real neighbours."""
        return self.idx >= 0

    @property
    def count(self) -> torch.Tensor:
        """[N] neighbour counts."""
        return self.valid.sum(1)


def contact_voxel_points(scene: Scene, cfg: Config, generator: torch.Generator) -> torch.Tensor:
    """Training points in ground-truth contact voxels (at most contacts.max_points voxels, one point each)."""
    s = scene.voxel_size_m
    dims = scene.dims
    voxels = torch.nonzero(scene.labels.reshape(-1) == 1).reshape(-1)
    if voxels.numel() > cfg.contacts.max_points:
        voxels = voxels[torch.randperm(voxels.numel(), generator=generator)[: cfg.contacts.max_points]]
        voxels = torch.sort(voxels).values
    n = voxels.numel()
    ijk = torch.stack([voxels // (dims[1] * dims[2]), (voxels // dims[2]) % dims[1], voxels % dims[2]], 1)
    uniform = (ijk.to(torch.float64) + torch.rand(n, 3, generator=generator, dtype=torch.float64)) * s
    if cfg.contacts.rule == "voxel-uniform" or len(scene.contact) == 0 or n == 0:
        return uniform.to(torch.float32)
    # jittered-contact: a random true contact inside the voxel, plus a uniform jitter in a ball.
    gc = torch.floor(scene.contact.to(torch.float64) / s).to(torch.int64)
    gc = gc.clamp(min=torch.zeros(3, dtype=torch.int64), max=torch.tensor(dims) - 1)
    gkey = (gc[:, 0] * dims[1] + gc[:, 1]) * dims[2] + gc[:, 2]
    skeys, order = torch.sort(gkey, stable=True)
    start = torch.searchsorted(skeys, voxels)
    end = torch.searchsorted(skeys, voxels, right=True)
    count = end - start
    pick = start + torch.floor(torch.rand(n, generator=generator, dtype=torch.float64) * count).to(torch.int64)
    pick = pick.clamp(max=max(len(order) - 1, 0))
    base = scene.contact[order[pick]].to(torch.float64)
    direction = torch.randn(n, 3, generator=generator, dtype=torch.float64)
    direction = direction / direction.norm(dim=1, keepdim=True).clamp_min(1e-12)
    radius = cfg.contacts.jitter_m * torch.rand(n, 1, generator=generator, dtype=torch.float64).pow(1.0 / 3.0)
    jittered = base + direction * radius
    return torch.where((count > 0).unsqueeze(1), jittered, uniform).to(torch.float32)


def uniform_contact_points(scene: Scene, cfg: Config, generator: torch.Generator) -> torch.Tensor:
    """The paper's training points: one uniform point in each of at most contacts.uniform_points random
    ground-truth contact voxels (none, and no random draw, when it is 0)."""
    if cfg.contacts.uniform_points == 0:
        return torch.zeros(0, 3)
    paper = replace(cfg, contacts=replace(cfg.contacts, rule="voxel-uniform", max_points=cfg.contacts.uniform_points))
    return contact_voxel_points(scene, paper, generator)


def predicted_voxel_points(scene: Scene, p_contact: torch.Tensor, cfg: Config, generator: torch.Generator) -> torch.Tensor:
    """Uniform points in predicted contact voxels (P_contact ≥ threshold) that are not true contact voxels."""
    if cfg.contacts.predicted_points == 0:
        return torch.zeros(0, 3)
    flat = p_contact.detach().reshape(-1)
    cand = torch.nonzero((flat >= cfg.contacts.predicted_probability) & (scene.labels.reshape(-1) != 1)).reshape(-1)
    if cand.numel() > cfg.contacts.predicted_points:
        cand = cand[torch.randperm(cand.numel(), generator=generator)[: cfg.contacts.predicted_points]]
        cand = torch.sort(cand).values
    dims = scene.dims
    ijk = torch.stack([cand // (dims[1] * dims[2]), (cand // dims[2]) % dims[1], cand % dims[2]], 1)
    pts = (ijk.to(torch.float64) + torch.rand(cand.numel(), 3, generator=generator, dtype=torch.float64)) * scene.voxel_size_m
    return pts.to(torch.float32)


@dataclass
class GraspTargets:
    """Neighbour-derived labels of N points."""

    neighbours: Neighbours
    has: torch.Tensor  #: [N] bool, ≥ 1 neighbour
    nu_hat: torch.Tensor  #: [N, 3] normalised mean neighbour baseline (zeros without neighbours)
    width_hat: torch.Tensor  #: [N] mean neighbour width
    quality: torch.Tensor  #: [N] max neighbour quality (0 without neighbours)
    collision: torch.Tensor  #: [N, 18] mean neighbour σ flags


def grasp_targets(scene: Scene, index: GraspIndex, points: torch.Tensor, cfg: Config) -> GraspTargets:
    """Label points by their neighbour grasps."""
    nb = index.query(points, cfg.contacts.neighbour_radius_m, cfg.contacts.max_neighbours)
    n = len(points)
    if len(scene.contact) == 0:  # a scene without grasps: every point is a negative
        return GraspTargets(nb, torch.zeros(n, dtype=torch.bool), torch.zeros(n, 3), torch.zeros(n),
                            torch.zeros(n), torch.zeros(n, N_APPROACHES))
    valid = nb.valid
    has = valid.any(1)
    safe = nb.idx.clamp(min=0)
    vf = valid.to(torch.float32)
    cnt = vf.sum(1).clamp_min(1.0)
    b = scene.baseline[safe] * vf.unsqueeze(-1)  # [N, k, 3]
    mean_b = b.sum(1)
    norm = mean_b.norm(dim=1, keepdim=True)
    nearest = scene.baseline[safe[:, 0]]
    # Opposite neighbour baselines can cancel: fall back to the nearest neighbour's baseline.
    nu_hat = torch.where(norm > 1e-3, mean_b / norm.clamp_min(1e-12), nearest) * has.unsqueeze(1)
    width_hat = (scene.width[safe] * vf).sum(1) / cnt
    quality = (scene.quality[safe] * vf).amax(1) if len(scene.quality) else torch.zeros(len(points))
    collision = (scene.collision_free[safe] * vf.unsqueeze(-1)).sum(1) / cnt.unsqueeze(1)
    return GraspTargets(nb, has, nu_hat, width_hat, quality * has, collision)


def decoded_scores(probabilities: torch.Tensor, mlp_out: dict[str, torch.Tensor], points: torch.Tensor,
                   baseline: torch.Tensor, width: torch.Tensor, extent_m: list[float],
                   approach_depth_m: float) -> tuple[torch.Tensor, torch.Tensor]:
    """q = I(P_c, c)·q′ and σ_i = I(P_t, t_i)·σ′_i with approach points from the given baseline and width."""
    a = approach_vectors(baseline)
    t = (points + 0.5 * width.unsqueeze(-1) * baseline).unsqueeze(1) - a * approach_depth_m
    q = sample_grid(probabilities[:, 1:2], points, extent_m)[:, 0] * mlp_out["quality_prior"]
    i_t = sample_grid(probabilities[:, 2:3], t.reshape(-1, 3), extent_m)[:, 0].reshape(-1, N_APPROACHES)
    return q, i_t * mlp_out["collision_prior"]


def grasp_loss(scene: Scene, targets: GraspTargets, points: torch.Tensor, mlp_out: dict[str, torch.Tensor],
               probabilities: torch.Tensor, cfg: Config, approach_depth_m: float) -> dict[str, torch.Tensor]:
    """The grasp loss terms (unweighted) and their weighted sum ``grasp``.

    * baseline: mean over neighbours of −log PS(b_n | ν, κ), each weighted by quality^p with
      ``loss.baseline_quality_power`` p > 0 (variant 1app-cosine: 1 − cos(ν, ν̂));
    * approach: −log Σσ_i PS(a | R_γi R⊥ ν̂, κ)/Σσ_i over the collision-free approaches of every neighbour;
    * width: min over neighbours of the mean endpoint distance between (c, c + w ν̂) and (c_n, c_n + w_n b_n);
    * quality: |q − max neighbour quality| (all points, target 0 without neighbours);
    * collision: BCE of σ_i against the mean neighbour flag.
    baseline/approach/width/collision use only points with ≥ 1 neighbour.
    """
    lc = cfg.loss
    zero = points.new_zeros(())
    has = targets.has
    nu, kappa, w = mlp_out["baseline"], mlp_out["kappa"], mlp_out["width"]
    extent = scene.extent_m
    nu_hat = targets.nu_hat.detach()
    q, sigma = decoded_scores(probabilities, mlp_out, points, nu_hat, targets.width_hat, extent, approach_depth_m)
    terms: dict[str, torch.Tensor] = {"quality": (q - targets.quality).abs().mean() if len(points) else zero}
    if not bool(has.any()):
        terms.update(baseline=zero, approach=zero, width=zero, collision=zero)
    else:
        h = has.nonzero().reshape(-1)
        nb_idx = targets.neighbours.idx[h]
        valid = nb_idx >= 0
        safe = nb_idx.clamp(min=0)
        vf = valid.to(points.dtype)
        b_n = scene.baseline[safe]  # [H, k, 3]
        nu_h, kappa_h = nu[h], kappa[h]
        if cfg.kappa_learned:
            lp = ps.log_prob(b_n, nu_h.unsqueeze(1), kappa_h.unsqueeze(1))  # [H, k]
            weight = vf
            if lc.baseline_quality_power > 0:
                weight = vf * scene.quality[safe].clamp_min(1e-6) ** lc.baseline_quality_power
            terms["baseline"] = (-(lp * weight).sum(1) / weight.sum(1)).mean()
        else:
            terms["baseline"] = (1.0 - F.cosine_similarity(nu_h, nu_hat[h], dim=1)).mean()
        # Approach NLL: mixture components around ν̂'s approach vectors, weights σ (floored).
        comp = approach_vectors(nu_hat[h])  # [H, 18, 3]
        a_n = approach_vectors(b_n)  # [H, k, 18, 3]
        dot = torch.einsum("hnjc,hic->hnji", a_n, comp)  # [H, k, 18 (true j), 18 (component i)]
        lp_a = ps.log_prob_from_dot(dot, kappa_h[:, None, None, None])
        sig = sigma[h].clamp(lc.sigma_floor, 1.0)
        log_mix = torch.logsumexp(lp_a + sig.log()[:, None, None, :], dim=-1) - sig.sum(1).log()[:, None, None]
        free = scene.collision_free[safe] * vf.unsqueeze(-1)  # [H, k, 18]
        per_point = -(log_mix * free).sum((1, 2)) / free.sum((1, 2)).clamp_min(1.0)
        terms["approach"] = per_point.mean()
        # Width: pair distance with the label baseline ν̂.
        c = points[h]
        c2 = c + w[h].unsqueeze(1) * nu_hat[h]
        cn = scene.contact[safe]
        cn2 = cn + scene.width[safe].unsqueeze(-1) * b_n
        d = 0.5 * ((c.unsqueeze(1) - cn).norm(dim=-1) + (c2.unsqueeze(1) - cn2).norm(dim=-1))
        d = torch.where(valid, d, torch.full_like(d, math.inf))
        terms["width"] = d.amin(1).mean() / lc.width_unit_m
        target = targets.collision[h]
        terms["collision"] = F.binary_cross_entropy(sigma[h].clamp(1e-6, 1 - 1e-6), target)
    terms["grasp"] = (lc.baseline * terms["baseline"] + lc.approach * terms["approach"] + lc.width * terms["width"]
                      + lc.quality * terms["quality"] + lc.collision * terms["collision"])
    return terms
