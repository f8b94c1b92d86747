import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from safetensors.numpy import save_file
from torch.nn import functional as F

from psgrasp_training.config import ConfigError, config_from_dict
from psgrasp_training.data import Scene, read_scene
from psgrasp_training.losses import GraspIndex, focal_loss, grasp_loss, grasp_targets, uniform_contact_points
from synthetic import make_scene


def test_focal_is_weighted_cross_entropy_at_gamma_zero():
    g = torch.Generator().manual_seed(0)
    logits = torch.randn(1, 3, 5, 4, 3, generator=g)
    labels = torch.randint(0, 3, (1, 5, 4, 3), generator=g)
    w = [0.1, 10.0, 5.0]
    ours = focal_loss(logits, labels, w, 0.0)
    ref = F.cross_entropy(logits, labels, weight=torch.tensor(w))
    assert torch.allclose(ours, ref, atol=1e-6)


def test_focal_hand_computed():
    # Two voxels: class 1 with p = 0.5, class 0 with p = 0.9 (two-class logits padded by −inf).
    logits = torch.tensor([[math.log(0.5), math.log(0.5), -1e9], [math.log(0.9), math.log(0.1), -1e9]]).t()
    logits = logits.reshape(1, 3, 2, 1, 1)
    labels = torch.tensor([1, 0]).reshape(1, 2, 1, 1)
    got = focal_loss(logits, labels, [0.1, 10.0, 5.0], 2.0)
    expected = (10 * 0.25 * math.log(2) + 0.1 * 0.01 * -math.log(0.9)) / 10.1
    assert abs(float(got) - expected) < 1e-6
    # Focusing lowers the loss of well-classified voxels relative to cross-entropy.
    assert float(got) < float(focal_loss(logits, labels, [0.1, 10.0, 5.0], 0.0))


def test_grasp_index_matches_brute_force():
    g = torch.Generator().manual_seed(2)
    contacts = torch.rand(3000, 3, generator=g) * 0.05
    points = torch.rand(400, 3, generator=g) * 0.05
    r, k = 0.003, 4
    nb = GraspIndex(contacts, r).query(points, r, k)
    d = torch.cdist(points.double(), contacts.double())
    for i in range(len(points)):
        within = torch.nonzero(d[i] <= r).reshape(-1)
        order = within[torch.argsort(d[i, within], stable=True)][:k]
        got = nb.idx[i][nb.idx[i] >= 0]
        assert got.tolist() == order.tolist()
    assert (nb.count > 0).any() and (nb.count == k).any() and (nb.count == 0).any()


def one_grasp_scene(flags_free=(5,)):
    free = torch.zeros(1, 18)
    free[0, list(flags_free)] = 1
    return Scene(
        normals=torch.zeros(3, 8, 8, 8), labels=torch.zeros(8, 8, 8, dtype=torch.int64),
        contact=torch.tensor([[0.05, 0.05, 0.05]]), baseline=torch.tensor([[1.0, 0.0, 0.0]]),
        width=torch.tensor([0.03]), quality=torch.tensor([0.8]), collision_free=free, voxel_size_m=0.0125,
    )


def outputs(baseline=(1.0, 0.0, 0.0), kappa=25.0, width=0.03, collision=None):
    if collision is None:
        collision = torch.zeros(1, 18)
        collision[0, 5] = 1.0
    return {
        "baseline": torch.tensor([baseline]), "kappa": torch.tensor([kappa]), "width": torch.tensor([width]),
        "quality_prior": torch.tensor([1.0]), "collision_prior": collision,
    }


def constant_probabilities(p_contact=0.8, p_gripper=1.0):
    p = torch.zeros(1, 3, 8, 8, 8)
    p[:, 1] = p_contact
    p[:, 2] = p_gripper
    return p


def run_loss(cfg, out, point=(0.05, 0.05, 0.05), scene=None):
    scene = scene or one_grasp_scene()
    pts = torch.tensor([point])
    t = grasp_targets(scene, GraspIndex(scene.contact, cfg.contacts.neighbour_radius_m), pts, cfg)
    return grasp_loss(scene, t, pts, out, constant_probabilities(), cfg, 0.039)


def test_grasp_loss_at_the_true_grasp():
    cfg = config_from_dict({})
    terms = run_loss(cfg, outputs())
    kappa = 25.0
    # PS NLL at ν = b: −(log C(κ) + κ ln 2) = −ln((κ+1)/(4π)).
    assert abs(float(terms["baseline"]) + math.log((kappa + 1) / (4 * math.pi))) < 1e-5
    assert float(terms["width"]) < 1e-4  # the predicted pair is the true pair
    assert float(terms["quality"]) < 1e-6  # I(P_c) q′ = 0.8 = max neighbour quality
    assert float(terms["collision"]) < 1e-4
    # Approach mixture with σ_5 = 1, others at the floor 1e-4; true approach a_5; components at Δγ = π|i−5|/17.
    floor = cfg.loss.sigma_floor
    dens = [(floor if i != 5 else 1.0) * (kappa + 1) / (2 ** (kappa + 2) * math.pi)
            * (1 + math.cos(math.pi * abs(i - 5) / 17)) ** kappa for i in range(18)]
    expected = -math.log(sum(dens) / (1 + 17 * floor))
    assert abs(float(terms["approach"]) - expected) < 1e-4
    assert float(terms["grasp"]) == pytest.approx(
        float(terms["baseline"]) + 0.01 * float(terms["approach"]) + 0.1 * float(terms["width"])
        + 10 * float(terms["quality"]) + 0.1 * float(terms["collision"]), rel=1e-6)


def test_grasp_loss_penalises_wrong_predictions():
    cfg = config_from_dict({})
    base = run_loss(cfg, outputs())
    wrong_b = run_loss(cfg, outputs(baseline=(0.0, 1.0, 0.0)))
    # Orthogonal ν: NLL grows by κ·ln 2.
    assert float(wrong_b["baseline"]) - float(base["baseline"]) == pytest.approx(25 * math.log(2), rel=1e-5)
    wide = run_loss(cfg, outputs(width=0.04))
    assert float(wide["width"]) == pytest.approx(5.0, rel=1e-4)  # (0 + 10 mm)/2
    uniform = run_loss(cfg, outputs(collision=torch.full((1, 18), 0.5)))
    assert float(uniform["approach"]) > float(base["approach"])
    assert float(uniform["collision"]) > 0.5


def test_quality_power_pulls_the_baseline_toward_the_more_antipodal_label():
    # Two labels at the same contact, orthogonal baselines, qualities 0.95 and 0.55.
    scene = one_grasp_scene()
    scene.contact = scene.contact.repeat(2, 1)
    scene.baseline = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    scene.width = scene.width.repeat(2)
    scene.quality = torch.tensor([0.95, 0.55])
    scene.collision_free = scene.collision_free.repeat(2, 1)
    at_good, at_poor = outputs(baseline=(1.0, 0.0, 0.0)), outputs(baseline=(0.0, 1.0, 0.0))
    plain = config_from_dict({})
    # The paper's mean over neighbours cannot tell the two apart.
    assert float(run_loss(plain, at_good, scene=scene)["baseline"]) == pytest.approx(
        float(run_loss(plain, at_poor, scene=scene)["baseline"]), rel=1e-6)
    # Weighted by quality^4: the NLL at the better label is lower by (w1 − w2)/(w1 + w2)·κ ln 2.
    weighted = config_from_dict({"loss": {"baseline_quality_power": 4.0}})
    w1, w2 = 0.95 ** 4, 0.55 ** 4
    gap = float(run_loss(weighted, at_poor, scene=scene)["baseline"]) - float(
        run_loss(weighted, at_good, scene=scene)["baseline"])
    assert gap == pytest.approx((w1 - w2) / (w1 + w2) * 25 * math.log(2), rel=1e-4)
    with pytest.raises(ConfigError, match="baseline_quality_power"):
        config_from_dict({"loss": {"baseline_quality_power": -1.0}})


def test_point_without_neighbours_only_trains_quality():
    cfg = config_from_dict({})
    terms = run_loss(cfg, outputs(), point=(0.02, 0.02, 0.02))
    assert float(terms["baseline"]) == 0 and float(terms["approach"]) == 0 and float(terms["width"]) == 0
    assert float(terms["quality"]) == pytest.approx(0.8)  # target 0, q = 0.8


def test_cosine_variant():
    cfg = config_from_dict({"variant": "1app-cosine"})
    assert float(run_loss(cfg, outputs())["baseline"]) == pytest.approx(0.0, abs=1e-6)
    assert float(run_loss(cfg, outputs(baseline=(0.0, 0.0, 1.0)))["baseline"]) == pytest.approx(1.0, abs=1e-6)


def test_loss_gradients_are_finite_for_antipodal_prediction():
    cfg = config_from_dict({})
    out = outputs(baseline=(-1.0, 0.0, 0.0))
    out["baseline"].requires_grad_(True)
    terms = run_loss(cfg, out)
    terms["grasp"].backward()
    assert torch.isfinite(terms["grasp"]) and torch.isfinite(out["baseline"].grad).all()


def test_scene_without_grasps():
    cfg = config_from_dict({})
    scene = one_grasp_scene()
    empty = Scene(normals=scene.normals, labels=scene.labels, contact=torch.zeros(0, 3), baseline=torch.zeros(0, 3),
                  width=torch.zeros(0), quality=torch.zeros(0), collision_free=torch.zeros(0, 18),
                  voxel_size_m=scene.voxel_size_m)
    terms = run_loss(cfg, outputs(), scene=empty)
    assert float(terms["baseline"]) == 0 and float(terms["quality"]) == pytest.approx(0.8)


def test_paper_rule_points_lie_in_contact_voxels_and_label_off_surface_points_negative(tmp_path, tiny_cfg):
    """contacts.uniform_points adds the paper's points: one uniform point in each of that many distinct
    ground-truth contact voxels; the ones farther than the neighbour radius from every true contact
    (off the surface, where inference's sub-voxel centres also sample) get quality target 0."""
    tensors, _ = make_scene(0, np.random.default_rng(5))
    save_file(tensors, str(tmp_path / "s.safetensors"))
    scene = read_scene(tmp_path / "s.safetensors")
    cfg = tiny_cfg()
    g = torch.Generator().manual_seed(1)
    state = g.get_state()
    assert uniform_contact_points(scene, cfg, g).shape == (0, 3)
    assert torch.equal(g.get_state(), state), "no draw when the option is off"

    voxels = int((scene.labels == 1).sum())
    assert voxels > 20
    cfg = replace(cfg, contacts=replace(cfg.contacts, uniform_points=voxels - 5))
    points = uniform_contact_points(scene, cfg, g)
    assert points.shape == (voxels - 5, 3)
    ijk = torch.floor(points / scene.voxel_size_m).to(torch.int64)
    assert bool((scene.labels[ijk[:, 0], ijk[:, 1], ijk[:, 2]] == 1).all()), "every point in a contact voxel"
    assert len(torch.unique(ijk, dim=0)) == len(points), "one point per voxel"
    targets = grasp_targets(scene, GraspIndex(scene.contact, cfg.contacts.neighbour_radius_m), points, cfg)
    nearest = torch.cdist(points.double(), scene.contact.double()).amin(1)
    far = nearest > cfg.contacts.neighbour_radius_m + 1e-6
    assert bool(far.any()) and bool((~far).any())
    assert bool((targets.quality[far] == 0).all()) and bool((targets.quality[~far] > 0).all())
    big = replace(cfg, contacts=replace(cfg.contacts, uniform_points=10 * voxels))
    assert len(uniform_contact_points(scene, big, g)) == voxels, "at most one point per contact voxel"
