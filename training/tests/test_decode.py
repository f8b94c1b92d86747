import math

import numpy as np
import torch

from psgrasp_training.decode import (SUBVOXEL_SIGNS, approach_vectors, contact_voxels, decode, sample_features,
                                     sample_grid, subvoxel_points)
from synthetic import approach_vectors_np


def trilinear_reference(grid: np.ndarray, p: np.ndarray, s: float) -> np.ndarray:
    """Hand-written network.md convention: u = p/s − 0.5 clamped to [0, dim−1], 8 neighbours."""
    c, dims = grid.shape[0], grid.shape[1:]
    u = np.clip(p / s - 0.5, 0, np.array(dims) - 1)
    i0 = np.floor(u).astype(int)
    i0 = np.minimum(i0, np.array(dims) - 1)
    i1 = np.minimum(i0 + 1, np.array(dims) - 1)
    f = u - i0
    out = np.zeros(c)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (f[0] if dx else 1 - f[0]) * (f[1] if dy else 1 - f[1]) * (f[2] if dz else 1 - f[2])
                idx = (i1[0] if dx else i0[0], i1[1] if dy else i0[1], i1[2] if dz else i0[2])
                out += w * grid[(slice(None), *idx)]
    return out


def test_grid_sample_matches_handwritten_trilinear():
    g = torch.Generator().manual_seed(0)
    dims, s = (6, 5, 4), 0.01
    grid = torch.randn(1, 2, *dims, generator=g)
    pts = [
        [0.025, 0.015, 0.005],  # voxel (2,1,0) centre exactly
        [0.0301, 0.0222, 0.0177],  # interior, non-aligned
        [0.0, 0.0, 0.0],  # below the first centre: clamped
        [0.06, 0.05, 0.04],  # grid maximum corner: clamped
        [-0.02, 0.07, 0.013],  # outside on two axes
    ] + (torch.rand(20, 3, generator=g) * torch.tensor([0.06, 0.05, 0.04])).tolist()
    p = torch.tensor(pts)
    got = sample_grid(grid, p, [d * s for d in dims])
    for k, q in enumerate(pts):
        ref = trilinear_reference(grid[0].double().numpy(), np.array(q), s)
        np.testing.assert_allclose(got[k].numpy(), ref, atol=1e-5)
    # Axis order: a value planted at voxel (i,j,k) is read back at its centre only.
    z = torch.zeros(1, 1, *dims)
    z[0, 0, 4, 1, 3] = 7.0
    got = sample_grid(z, torch.tensor([[0.045, 0.015, 0.035], [0.035, 0.015, 0.035], [0.045, 0.015, 0.025]]),
                      [0.06, 0.05, 0.04])[:, 0]
    assert abs(float(got[0]) - 7.0) < 1e-5 and abs(float(got[1])) < 1e-5 and abs(float(got[2])) < 1e-5


def test_features_use_level_voxel_sizes():
    s, dims = 0.01, (8, 8, 8)
    enc0 = torch.arange(512, dtype=torch.float32).reshape(1, 1, 8, 8, 8)
    enc1 = torch.arange(64, dtype=torch.float32).reshape(1, 1, 4, 4, 4) * 10
    p = torch.tensor([[0.05, 0.03, 0.07]])  # level-1 voxel size 0.02: u = (2, 1, 3)
    f = sample_features([enc0, enc1], p, [d * s for d in dims])
    assert f.shape == (1, 2)
    ref0 = trilinear_reference(enc0[0].numpy(), p[0].numpy(), s)
    assert abs(float(f[0, 0]) - ref0[0]) < 1e-4
    assert float(f[0, 1]) == float(enc1[0, 0, 2, 1, 3])


def test_approach_vectors_match_dataset_definition():
    g = torch.Generator().manual_seed(1)
    b = torch.randn(50, 3, generator=g, dtype=torch.float64)
    b = torch.cat([b, torch.tensor([[0.0, 0, 1], [0, 0, -1], [1, 0, 0]], dtype=torch.float64)])
    b = b / b.norm(dim=1, keepdim=True)
    a = approach_vectors(b)
    for k in range(len(b)):
        np.testing.assert_allclose(a[k].numpy(), approach_vectors_np(b[k].numpy()), atol=1e-12)
    assert torch.allclose((a * b[:, None]).sum(-1), torch.zeros(1, dtype=torch.float64), atol=1e-12)
    assert (a[..., 2] <= 1e-9).all()  # never upward
    assert torch.allclose(a[:, 0], -a[:, 17], atol=1e-12)
    ax = approach_vectors(torch.tensor([1.0, 0, 0]))
    assert ax[8, 2] < -0.98 and ax[9, 2] < -0.98


def test_contact_voxels_threshold_cap_and_ties():
    p = torch.zeros(2, 2, 2)
    p[0, 0, 1] = 0.9  # linear 1
    p[1, 0, 0] = 0.7  # linear 4
    p[1, 1, 1] = 0.7  # linear 7
    p[0, 1, 0] = 0.6  # linear 2
    assert contact_voxels(p, 0.5).tolist() == [1, 2, 4, 7]
    # Cap 2: 0.9 and the lower linear index of the 0.7 tie; output ascending.
    assert contact_voxels(p, 0.5, 2).tolist() == [1, 4]
    assert contact_voxels(p, 0.95).numel() == 0


def test_subvoxel_order():
    s = 0.008
    pts = subvoxel_points(torch.tensor([(1 * 3 + 2) * 4 + 3]), (2, 3, 4), s)  # voxel (1, 2, 3)
    centre = torch.tensor([1.5, 2.5, 3.5]) * s
    assert pts.shape == (8, 3)
    expected = centre + SUBVOXEL_SIGNS.float() * s / 4
    assert torch.allclose(pts, expected)
    # dx major, − before +.
    assert pts[0, 0] < centre[0] and pts[4, 0] > centre[0] and pts[1, 2] > pts[0, 2] and pts[2, 1] > pts[0, 1]


def test_decode_scores_on_constant_probabilities():
    dims, s = (8, 8, 8), 0.01
    probs = torch.zeros(1, 3, *dims)
    probs[:, 0] = 0.2
    probs[:, 1] = 0.5
    probs[:, 2] = 0.3
    probs[0, 2, :, :, 6:] = 0.9  # gripper space high above z = 0.06
    points = torch.tensor([[0.04, 0.04, 0.02]])
    out = {
        "baseline": torch.tensor([[1.0, 0.0, 0.0]]),
        "kappa": torch.tensor([30.0]),
        "width": torch.tensor([0.02]),
        "quality_prior": torch.tensor([0.8]),
        "collision_prior": torch.full((1, 18), 0.5),
    }
    dec = decode(probs, out, points, [d * s for d in dims], approach_depth_m=0.039)
    assert abs(float(dec.quality[0]) - 0.4) < 1e-6
    t = dec.approach_points[0]
    assert torch.allclose(t[8], torch.tensor([0.05, 0.04 + 0.039 * math.sin(math.pi / 34), 0.02 + 0.039 * math.cos(math.pi / 34)]), atol=1e-6)
    # Every σ_i = I(P_t, t_i) · 0.5 with the hand-written interpolation.
    for i in range(18):
        ref = trilinear_reference(probs[0, 2:3].numpy(), t[i].numpy(), s)[0] * 0.5
        assert abs(float(dec.collision_scores[0, i]) - ref) < 1e-6
    single = decode(probs, out, points, [d * s for d in dims], 0.039, single_approach=True)
    assert int((single.collision_scores > 0).sum()) == 1
    assert float(single.collision_scores.max()) == float(dec.collision_scores.max())
