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
from .data import MIN_LABEL_QUALITY, SceneDataset
from .decode import (approach_vectors, class_probabilities, contact_voxels, decode, sample_features,
                     subvoxel_points)
from .losses import GraspIndex
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


@dataclass
class Candidates:
    """The configurations the selection would consider, best q first (one approach each)."""

    points: torch.Tensor  #: [N, 3] contact points
    baselines: torch.Tensor  #: [N, 3]
    widths: torch.Tensor  #: [N]
    approaches: torch.Tensor  #: [N, 3] the first passing approach of the best `approaches_per_configuration`
    quality: torch.Tensor  #: [N] q, descending

    def __len__(self) -> int:
        return len(self.quality)

    def take(self, index: torch.Tensor | list[int]) -> "Candidates":
        """A subset, in the order of `index`."""
        index = torch.as_tensor(index, dtype=torch.int64)
        return Candidates(self.points[index], self.baselines[index], self.widths[index], self.approaches[index],
                          self.quality[index])


def scene_candidates(net: GraspNet, normals: torch.Tensor, extent_m: list[float], voxel_size_m: float,
                     contact_probability: float, approach_depth_m: float, pc: PickCheckConfig,
                     unet_out: tuple | None = None) -> Candidates:
    """Every configuration of one grid that passes the selection's thresholds (q, the best
    approaches' σ inside the tilt cone), ordered by q. `unet_out`: the U-Net's (logits, encs) of
    this grid when the caller already ran it (validation), so it runs once per scene."""
    device = next(net.parameters()).device
    logits, encs = unet_out if unet_out is not None else net.unet(normals.to(device).unsqueeze(0))
    probs = class_probabilities(logits)
    dims = list(normals.shape[1:])
    voxels = contact_voxels(probs[0, 1].cpu(), contact_probability, pc.max_contact_voxels)
    empty = Candidates(torch.zeros(0, 3), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3), torch.zeros(0))
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
    approach = d.approach_vectors[idx, order[idx, first[idx]]]
    ranked = torch.argsort(d.quality[idx], descending=True, stable=True)
    idx, approach = idx[ranked], approach[ranked]
    return Candidates(d.points[idx], d.baseline[idx], d.width[idx], approach, d.quality[idx])


def top_pick_indices(c: Candidates, pc: PickCheckConfig) -> list[int]:
    """Indices of the best `pc.k` candidates whose TCPs keep the pick spacing, best first."""
    tcp = c.points + 0.5 * c.widths.unsqueeze(-1) * c.baselines
    chosen: list[int] = []
    for r in range(len(c)):
        if all(float((tcp[r] - tcp[j]).norm()) >= pc.pick_spacing_m for j in chosen):
            chosen.append(r)
            if len(chosen) == pc.k:
                break
    return chosen


def top_picks(c: Candidates, pc: PickCheckConfig) -> Candidates:
    """The best `pc.k` candidates whose TCPs keep the pick spacing."""
    return c.take(top_pick_indices(c, pc))


def scene_picks(net: GraspNet, normals: torch.Tensor, extent_m: list[float], voxel_size_m: float,
                contact_probability: float, approach_depth_m: float, pc: PickCheckConfig):
    """The selection's best picks of one grid: (points, baselines, widths, approach vectors, q),
    at most pc.k, ordered by q."""
    p = top_picks(scene_candidates(net, normals, extent_m, voxel_size_m, contact_probability, approach_depth_m, pc),
                  pc)
    return p.points, p.baselines, p.widths, p.approaches, p.quality


def matched_labels(scene, points, baselines, widths, approaches, pc: PickCheckConfig,
                   max_neighbours: int = 32, chunk: int = 2048) -> torch.Tensor:
    """[N] index of a labelled good (quality above MIN_LABEL_QUALITY) collision-free grasp each
    pick matches (−1: none): contact within
    match_radius_m (the nearest `max_neighbours` labels), baseline within match_angle_deg, width
    within match_width_m, and a label approach within match_approach_deg of the pick's free."""
    n = len(points)
    out = torch.full((n,), -1, dtype=torch.int64)
    if n == 0 or len(scene.contact) == 0:
        return out
    index = GraspIndex(scene.contact, pc.match_radius_m)
    cos_angle = math.cos(math.radians(pc.match_angle_deg))
    cos_app = math.cos(math.radians(pc.match_approach_deg))
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        nb = index.query(points[s:e].float(), pc.match_radius_m, max_neighbours).idx  # [c, K]
        valid = nb >= 0
        g = nb.clamp(min=0)
        ok = valid & ((scene.baseline[g] * baselines[s:e, None]).sum(-1) >= cos_angle)
        ok &= (scene.width[g] - widths[s:e, None]).abs() <= pc.match_width_m
        ok &= scene.quality[g] > MIN_LABEL_QUALITY  # not a label that failed the physics check
        if not bool(ok.any()):
            continue
        rows, cols = ok.nonzero(as_tuple=True)
        gt = g[rows, cols]
        gt_app = approach_vectors(scene.baseline[gt].to(torch.float64)).to(torch.float32)  # [P, 18, 3]
        close = (gt_app * approaches[s:e][rows, None]).sum(-1) >= cos_app
        hit = (close & (scene.collision_free[gt] > 0.5)).any(1)
        # The first (nearest) matching label per pick.
        for r, lab in zip(rows[hit].tolist(), gt[hit].tolist()):
            if out[s + r] < 0:
                out[s + r] = lab
    return out


def pick_matches(scene, points, baselines, widths, approaches, pc: PickCheckConfig) -> list[bool]:
    """Whether each pick matches a labelled collision-free grasp of the scene."""
    return (matched_labels(scene, points, baselines, widths, approaches, pc) >= 0).tolist()


class PickStats:
    """The pick check's counts, scene by scene, per scene-size group and pooled."""

    def __init__(self, pc: PickCheckConfig):
        self.pc = pc
        self.stats: dict[str, dict[str, float]] = {}

    def add(self, scene, objects: int, cands: Candidates) -> None:
        """Count one scene from its candidates (every candidate matched once: the top picks'
        matches and the objects covered)."""
        pc = self.pc
        hit = matched_labels(scene, cands.points, cands.baselines, cands.widths, cands.approaches, pc)
        matches = (hit[top_pick_indices(cands, pc)] >= 0).tolist()
        # Object recall: objects with a collision-free label that some candidate matches.
        labelled = covered = 0
        if scene.object is not None and len(scene.contact):
            free = scene.collision_free.sum(1) > 0
            labelled = int(torch.unique(scene.object[free]).numel())
            covered = int(torch.unique(scene.object[hit[hit >= 0]]).numel())
        for name in (_group(objects, pc.groups), "all"):
            s = self.stats.setdefault(name, {"scenes": 0, "matched": 0, "top1": 0, "no_pick": 0, "labelled": 0,
                                             "covered": 0})
            s["scenes"] += 1
            s["matched"] += sum(matches)
            s["top1"] += int(bool(matches) and matches[0])
            s["no_pick"] += int(not matches)
            s["labelled"] += labelled
            s["covered"] += covered

    def result(self) -> dict:
        """precision_at_k, top1, no_pick and object_recall per group."""
        k = self.pc.k
        return {name: {"scenes": s["scenes"], "precision_at_k": s["matched"] / (k * s["scenes"]),
                       "top1": s["top1"] / s["scenes"], "no_pick": s["no_pick"] / s["scenes"],
                       "object_recall": s["covered"] / s["labelled"] if s["labelled"] else 0.0}
                for name, s in self.stats.items()}


@torch.no_grad()
def pick_check(net: GraspNet, ds: SceneDataset, cfg: Config, max_scenes: int = 0,
               pc: PickCheckConfig | None = None, all_scenes: bool = False) -> dict:
    """The pick check over the held-out scenes (see the module doc); `all_scenes`: over every
    scene of the dataset (one generated for checking only, e.g. test objects on an unreported seed)."""
    pc = pc or PickCheckConfig()
    was_training = net.training
    net.eval()
    entries = sorted(ds.train_entries + ds.val_entries, key=lambda e: e["index"]) if all_scenes else ds.val_entries
    entries = entries[:max_scenes] if max_scenes > 0 else entries
    stats = PickStats(pc)
    for entry in entries:
        scene = ds.scene(entry)
        stats.add(scene, int(entry.get("objects", 0)),
                  scene_candidates(net, scene.normals, scene.extent_m, scene.voxel_size_m,
                                   cfg.export.contact_probability, cfg.grid.approach_depth_m, pc))
    if was_training:
        net.train()
    return stats.result()
