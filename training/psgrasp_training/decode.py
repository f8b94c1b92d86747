"""Contact sampling, feature sampling and decoding, exactly as network contract v1 (and the Rust side).

Conventions: points are metres in the workspace frame (origin at the grid's minimum corner); a grid
has tensor axes [X, Y, Z]; level l of the U-Net has voxel size s·2^l and the same extent. Trilinear
sampling at p uses u = p/s_l − 0.5 per axis clamped to [0, dim − 1] — in PyTorch
``grid_sample(..., align_corners=False, padding_mode="border")`` with g = 2p/extent − 1 and the
coordinate order reversed (g[..., 0] ↔ Z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch.nn import functional as F

from .model import N_APPROACHES

#: γ range of the approach vectors.
GAMMA_MIN = math.pi / 2
GAMMA_MAX = 3 * math.pi / 2


def approach_angles(count: int = N_APPROACHES) -> torch.Tensor:
    """γ_i = π/2 + π·i/(count − 1), i = 0..count−1."""
    return torch.tensor([GAMMA_MIN + (GAMMA_MAX - GAMMA_MIN) * i / (count - 1) for i in range(count)],
                        dtype=torch.float64)


def baseline_perpendicular(b: torch.Tensor) -> torch.Tensor:
    """b⊥ = normalize(up − (up·b) b), up = z; x = (1,0,0) instead of up when that norm < 1e-3. b: [..., 3] unit."""
    up = torch.zeros_like(b)
    up[..., 2] = 1.0
    x = torch.zeros_like(b)
    x[..., 0] = 1.0
    p_up = up - (b * up).sum(-1, keepdim=True) * b
    n_up = p_up.norm(dim=-1, keepdim=True)
    p_x = x - (b * x).sum(-1, keepdim=True) * b
    p = torch.where(n_up < 1e-3, p_x, p_up)
    return p / p.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def rotate_about(axis: torch.Tensor, v: torch.Tensor, cos: torch.Tensor, sin: torch.Tensor) -> torch.Tensor:
    """Rodrigues rotation of v about the unit axis (right-hand rule); cos/sin broadcast against [..., 1]."""
    return v * cos + torch.cross(axis, v, dim=-1) * sin + axis * (axis * v).sum(-1, keepdim=True) * (1.0 - cos)


def approach_vectors(b: torch.Tensor, count: int = N_APPROACHES) -> torch.Tensor:
    """a_i = R(b, γ_i) b⊥ for unit baselines b [..., 3] → [..., count, 3]."""
    perp = baseline_perpendicular(b)
    gamma = approach_angles(count).to(dtype=b.dtype, device=b.device)
    cos = torch.cos(gamma).unsqueeze(-1)
    sin = torch.sin(gamma).unsqueeze(-1)
    return rotate_about(b.unsqueeze(-2), perp.unsqueeze(-2), cos, sin)


def sample_grid(grid: torch.Tensor, points: torch.Tensor, extent_m: torch.Tensor | list[float]) -> torch.Tensor:
    """Trilinear sample of grid [1, C, X, Y, Z] at points [N, 3] (m) → [N, C] (clamped border convention)."""
    extent = torch.as_tensor(extent_m, dtype=points.dtype, device=points.device)
    g = 2.0 * points / extent - 1.0
    g = g.flip(-1).reshape(1, -1, 1, 1, 3).to(grid.dtype)
    out = F.grid_sample(grid, g, mode="bilinear", padding_mode="border", align_corners=False)
    return out.reshape(grid.shape[1], -1).t()


def grid_extent(dims: tuple[int, ...] | list[int], voxel_size_m: float) -> list[float]:
    """Extent of a grid in metres per axis."""
    return [d * voxel_size_m for d in dims]


def sample_features(encs: list[torch.Tensor], points: torch.Tensor, extent_m: list[float]) -> torch.Tensor:
    """Concatenated trilinear features of every encoder level at points [N, 3] → [N, F]."""
    return torch.cat([sample_grid(e, points, extent_m) for e in encs], dim=1)


def contact_voxels(p_contact: torch.Tensor, threshold: float, max_voxels: int | None = None) -> torch.Tensor:
    """Linear indices (ascending) of voxels with P_contact ≥ threshold; if more than max_voxels, the
    highest P_contact are kept (ties → lower linear index). p_contact: [X, Y, Z]."""
    flat = p_contact.reshape(-1)
    idx = torch.nonzero(flat >= threshold).reshape(-1)
    if max_voxels is not None and idx.numel() > max_voxels:
        # Stable sort on −P keeps ascending linear order among equal probabilities.
        order = torch.sort(-flat[idx], stable=True).indices[:max_voxels]
        idx = torch.sort(idx[order]).values
    return idx


def voxel_centres(linear: torch.Tensor, dims: list[int] | tuple[int, ...], voxel_size_m: float) -> torch.Tensor:
    """Centres [V, 3] (m) of voxels given by linear index (i·Y + j)·Z + k."""
    _, ny, nz = dims
    i = linear // (ny * nz)
    j = (linear // nz) % ny
    k = linear % nz
    return (torch.stack([i, j, k], dim=1).to(torch.float64) + 0.5) * voxel_size_m


#: Sub-voxel offsets in units of s/4: dx major, then dy, then dz, − before +.
SUBVOXEL_SIGNS = torch.tensor([[dx, dy, dz] for dx in (-1, 1) for dy in (-1, 1) for dz in (-1, 1)], dtype=torch.float64)


def subvoxel_points(linear: torch.Tensor, dims: list[int] | tuple[int, ...], voxel_size_m: float) -> torch.Tensor:
    """The 8 sub-voxel centres of each voxel, [8V, 3] float32, voxel-major."""
    centres = voxel_centres(linear, dims, voxel_size_m)
    pts = centres.unsqueeze(1) + SUBVOXEL_SIGNS.unsqueeze(0) * (voxel_size_m / 4.0)
    return pts.reshape(-1, 3).to(torch.float32)


@dataclass
class Decoded:
    """Decoded grasp configurations at M points."""

    points: torch.Tensor  #: [M, 3] contact points c
    baseline: torch.Tensor  #: [M, 3]
    kappa: torch.Tensor  #: [M]
    width: torch.Tensor  #: [M]
    quality: torch.Tensor  #: [M] q = I(P_contact, c)·q′
    collision_scores: torch.Tensor  #: [M, 18] σ_i = I(P_gripper, t_i)·σ′_i
    approach_vectors: torch.Tensor  #: [M, 18, 3]
    approach_points: torch.Tensor  #: [M, 18, 3] t_i


def class_probabilities(label_logits: torch.Tensor) -> torch.Tensor:
    """Softmax over the class axis of [1, 3, X, Y, Z]."""
    return torch.softmax(label_logits, dim=1)


def decode(probabilities: torch.Tensor, mlp_out: dict[str, torch.Tensor], points: torch.Tensor, extent_m: list[float],
           approach_depth_m: float, single_approach: bool = False) -> Decoded:
    """Decode MLP outputs at points into grasp configurations (network contract step 4–5).

    probabilities: [1, 3, X, Y, Z] softmax of the label logits; points [M, 3]."""
    b = mlp_out["baseline"]
    w = mlp_out["width"]
    a = approach_vectors(b)  # [M, 18, 3]
    tcp = points + 0.5 * w.unsqueeze(-1) * b
    t = tcp.unsqueeze(1) - a * approach_depth_m  # [M, 18, 3]
    p_contact = probabilities[:, 1:2]
    p_gripper = probabilities[:, 2:3]
    q = sample_grid(p_contact, points, extent_m)[:, 0] * mlp_out["quality_prior"]
    m = points.shape[0]
    i_t = sample_grid(p_gripper, t.reshape(-1, 3), extent_m)[:, 0].reshape(m, N_APPROACHES)
    sigma = i_t * mlp_out["collision_prior"]
    if single_approach and m > 0:
        best = sigma.argmax(dim=1, keepdim=True)
        sigma = torch.zeros_like(sigma).scatter(1, best, sigma.gather(1, best))
    return Decoded(points, b, mlp_out["kappa"], w, q, sigma, a, t)
