"""A cheap validation that looks at what the evaluation executes: the top picks.

Clutter clearing (`psgrasp eval`) executes, per frame, the best few configurations that pass the
selection's thresholds; a model is good there when those few are real grasps, whatever it predicts
elsewhere in the grid. The voxel and per-point metrics of :func:`psgrasp_training.train.evaluate`
do not measure that. This check runs the inference rule on the full grid of each held-out scene
(contact voxels at the card threshold, 8 sub-voxel points each, the MLP, q = P_contact · q′ and
σ_i = P_gripper · σ′_i), keeps the configurations the selection would consider (q and the best
approach's σ at their thresholds, approach tilt within the cone), takes the best ``k`` by q with
the selection's pick spacing, and scores each pick against the scene's ground-truth labels: a
pick matches when a labelled grasp has its contact within ``match_radius_m``, its baseline within
``match_angle_deg``, its width within ``match_width_m`` and the pick's approach collision-free.

Reported per scene-size group (the object counts of the paper's levels) and pooled:
``precision_at_k`` (matched picks over k, a scene with fewer picks counts the missing ones as
misses), ``top1`` (share of scenes whose first pick matches) and ``no_pick`` (share of scenes
with no pick at all — the evaluation's "no grasp" round end). No physics, no collision check
against the scene: a ranking aid, not a replacement for `psgrasp eval`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .config import Config
from .data import SceneDataset
from .decode import (approach_vectors, class_probabilities, contact_voxels, decode, sample_features,
                     subvoxel_points)
from .model import GraspNet


@dataclass
class PickCheckConfig:
    """Thresholds of the pick check (the selection's defaults; matching tolerances)."""

    k: int = 5
    min_quality: float = 0.5
    min_collision_score: float = 0.5
    approaches_per_configuration: int = 8
    max_approach_tilt_deg: float = 60.0
    pick_spacing_m: float = 0.05
    max_contact_voxels: int = 4096
    match_radius_m: float = 0.009
    match_angle_deg: float = 20.0
    match_width_m: float = 0.01
    match_approach_deg: float = 15.0
    #: Upper object counts of the groups (the paper's easy / medium / challenging).
    groups: tuple[tuple[str, int], ...] = (("easy", 5), ("medium", 15), ("challenging", 1 << 30))


def _group(objects: int, groups) -> str:
    for name, upper in groups:
        if objects <= upper:
            return name
    return groups[-1][0]


def scene_picks(net: GraspNet, normals: torch.Tensor, extent_m: list[float], voxel_size_m: float,
                contact_probability: float, approach_depth_m: float, pc: PickCheckConfig):
    """The selection's best picks of one grid: (points, baselines, widths, approach vectors, q),
    at most pc.k, ordered by q."""
    device = next(net.parameters()).device
    logits, encs = net.unet(normals.to(device).unsqueeze(0))
    probs = class_probabilities(logits)
    dims = list(normals.shape[1:])
    voxels = contact_voxels(probs[0, 1].cpu(), contact_probability, pc.max_contact_voxels)
    empty = (torch.zeros(0, 3), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3), torch.zeros(0))
    if voxels.numel() == 0:
        return empty
    points = subvoxel_points(voxels, dims, voxel_size_m).to(device)
    out = net.mlp(sample_features(encs, points, extent_m))
    d = decode(probs.cpu(), {k: v.cpu() for k, v in out.items()}, points.cpu(), extent_m, approach_depth_m)
    cos_tilt = math.cos(math.radians(pc.max_approach_tilt_deg))
    tilt_ok = (-d.approach_vectors[..., 2]) >= cos_tilt  # [M, 18]
    # The selection examines the best `approaches_per_configuration` approaches by σ.
    sigma = d.collision_scores
    order = torch.argsort(sigma, dim=1, descending=True)[:, : pc.approaches_per_configuration]
    ok = (sigma.gather(1, order) >= pc.min_collision_score) & tilt_ok.gather(1, order)
    first = torch.where(ok.any(1), ok.float().argmax(1), torch.full((len(ok),), -1))
    keep = (first >= 0) & (d.quality >= pc.min_quality)
    idx = keep.nonzero().reshape(-1)
    if idx.numel() == 0:
        return empty
    approach_index = order[idx, first[idx]]
    approach = d.approach_vectors[idx, approach_index]
    tcp = d.points[idx] + 0.5 * d.width[idx].unsqueeze(-1) * d.baseline[idx]
    ranked = torch.argsort(d.quality[idx], descending=True, stable=True)
    chosen: list[int] = []
    for r in ranked.tolist():
        if all(float((tcp[r] - tcp[c]).norm()) >= pc.pick_spacing_m for c in chosen):
            chosen.append(r)
            if len(chosen) == pc.k:
                break
    sel = idx[chosen]
    return d.points[sel], d.baseline[sel], d.width[sel], approach[chosen], d.quality[sel]


def pick_matches(scene, points, baselines, widths, approaches, pc: PickCheckConfig) -> list[bool]:
    """Whether each pick matches a labelled collision-free grasp of the scene."""
    result = []
    if len(scene.contact) == 0:
        return [False] * len(points)
    cos_angle = math.cos(math.radians(pc.match_angle_deg))
    cos_app = math.cos(math.radians(pc.match_approach_deg))
    for p, b, w, a in zip(points, baselines, widths, approaches):
        near = ((scene.contact - p).norm(dim=1) <= pc.match_radius_m).nonzero().reshape(-1)
        if near.numel():
            near = near[((scene.baseline[near] * b).sum(1) >= cos_angle)
                        & ((scene.width[near] - w).abs() <= pc.match_width_m)]
        matched = False
        if near.numel():
            gt_app = approach_vectors(scene.baseline[near].to(torch.float64)).to(torch.float32)  # [n, 18, 3]
            close = (gt_app * a).sum(-1) >= cos_app  # [n, 18]
            matched = bool((close & (scene.collision_free[near] > 0.5)).any())
        result.append(matched)
    return result


@torch.no_grad()
def pick_check(net: GraspNet, ds: SceneDataset, cfg: Config, max_scenes: int = 0,
               pc: PickCheckConfig | None = None) -> dict:
    """The pick check over the held-out scenes (see the module doc)."""
    pc = pc or PickCheckConfig()
    was_training = net.training
    net.eval()
    entries = ds.val_entries[:max_scenes] if max_scenes > 0 else ds.val_entries
    stats: dict[str, dict[str, float]] = {}
    for entry in entries:
        scene = ds.scene(entry)
        objects = int(entry.get("objects", 0))
        picks = scene_picks(net, scene.normals, scene.extent_m, scene.voxel_size_m, cfg.export.contact_probability,
                            cfg.grid.approach_depth_m, pc)
        matches = pick_matches(scene, *picks[:4], pc)
        for name in (_group(objects, pc.groups), "all"):
            s = stats.setdefault(name, {"scenes": 0, "matched": 0, "top1": 0, "no_pick": 0})
            s["scenes"] += 1
            s["matched"] += sum(matches)
            s["top1"] += int(bool(matches) and matches[0])
            s["no_pick"] += int(not matches)
    if was_training:
        net.train()
    return {name: {"scenes": s["scenes"], "precision_at_k": s["matched"] / (pc.k * s["scenes"]),
                   "top1": s["top1"] / s["scenes"], "no_pick": s["no_pick"] / s["scenes"]}
            for name, s in stats.items()}
