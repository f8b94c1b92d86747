"""The VGN-style baseline (variant ``vgn``): one grasp per voxel, retrained on our data.

As the paper retrained VGN (Breyer et al., CoRL 2020) for its comparison, this module trains a
fully convolutional network on the same scenes and labels as the two-stage model, with VGN's
targets: every voxel that holds the centre of at least one labelled grasp (collision-free approach,
quality > 0.5) is a positive with the single best-quality orientation and width found there; every
other voxel is a negative. Per voxel the network predicts a grasp quality, an orientation and an
opening width (VGN's three heads).

Deviations from VGN, all documented in ``training/README.md``: the input is our normal grid (3
channels, the input the two-stage model gets) instead of a TSDF; the orientation is predicted as a
baseline and an approach vector (the 6-D rotation representation) instead of a quaternion, with the
gripper's symmetry (b, a) ≡ (−b, a) in the loss; upsampling uses transposed convolutions (kernel =
stride = 2); the quality loss averages positives and negatives separately (VGN's data set samples
them in balance; dense voxel labels do not).

Graph contract (``vgn.onnx``): input ``normal_grid`` [1, 3, X, Y, Z]; outputs ``quality`` [1, 1, X,
Y, Z] (sigmoid), ``baseline`` [1, 3, X, Y, Z] (unit), ``approach`` [1, 3, X, Y, Z] (unit, ⟂
baseline), ``width`` [1, 1, X, Y, Z] (m). The grasp of voxel (i, j, k) is centred on the voxel centre.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from . import __version__
from .checkpoint import DatasetInfo, load_checkpoint
from .config import Config
from .data import MIN_LABEL_QUALITY, Scene, SceneDataset, read_scene
from .decode import approach_vectors
from .model import Conv3d, ConvTranspose3d

#: Output names of ``vgn.onnx`` in order.
VGN_OUTPUTS = ("quality", "baseline", "approach", "width")
#: Card format of VGN-style model directories.
VGN_CARD_FORMAT = "psgrasp-vgn-model"
VGN_FORMAT_VERSION = 1
#: Weight of the width MSE (in voxel units), as VGN.
WIDTH_WEIGHT = 0.01
LOG_FIELDS = ["step", "loss", "quality", "rotation", "width", "positives", "lr", "seconds", "elapsed_s"]
#: Middle of the approach index range: ties in quality go to the most vertical approach.
_MID_APPROACH = 8.5


class VgnNet(nn.Module):
    """VGN's encoder–decoder: three stride-2 convolutions (5³, 3³, 3³), three convolution + 2×
    upsampling stages, and 3³ heads for quality, baseline, approach and width at full resolution."""

    def __init__(self, base_channels: int = 16, in_channels: int = 3):
        super().__init__()
        c = [base_channels, 2 * base_channels, 4 * base_channels]
        self.channels = c
        self.encoder = nn.Sequential(
            Conv3d(in_channels, c[0], 5, stride=2, padding=2), nn.ReLU(inplace=True),
            Conv3d(c[0], c[1], 3, stride=2, padding=1), nn.ReLU(inplace=True),
            Conv3d(c[1], c[2], 3, stride=2, padding=1), nn.ReLU(inplace=True),
        )
        self.decoder = nn.Sequential(
            Conv3d(c[2], c[2], 3, padding=1), nn.ReLU(inplace=True), ConvTranspose3d(c[2], c[2], 2, stride=2),
            Conv3d(c[2], c[1], 3, padding=1), nn.ReLU(inplace=True), ConvTranspose3d(c[1], c[1], 2, stride=2),
            Conv3d(c[1], c[0], 3, padding=1), nn.ReLU(inplace=True), ConvTranspose3d(c[0], c[0], 2, stride=2),
        )
        self.head = Conv3d(c[0], 1 + 3 + 3 + 1, 3, padding=1)

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        """Raw heads: ``quality_logit`` [B,1,...], ``baseline``/``approach`` [B,3,...] (not normalised),
        ``width_vox`` [B,1,...] (voxel units)."""
        y = self.head(self.decoder(self.encoder(x)))
        return {"quality_logit": y[:, 0:1], "baseline": y[:, 1:4], "approach": y[:, 4:7], "width_vox": y[:, 7:8]}


def _unit_baseline_and_orthogonal_approach(baseline_raw: torch.Tensor, approach_raw: torch.Tensor,
                                           eps: float = 1e-8) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit baseline and the raw approach's part orthogonal to it, not normalised (channel dim 1)."""
    b = baseline_raw / baseline_raw.norm(dim=1, keepdim=True).clamp_min(eps)
    return b, approach_raw - (approach_raw * b).sum(1, keepdim=True) * b


def orientation(baseline_raw: torch.Tensor, approach_raw: torch.Tensor, eps: float = 1e-8):
    """Unit baseline and the approach made orthogonal to it and unit (channel dim 1)."""
    b, a = _unit_baseline_and_orthogonal_approach(baseline_raw, approach_raw, eps)
    return b, a / a.norm(dim=1, keepdim=True).clamp_min(eps)


def approach_orthogonal_share(out: dict[str, torch.Tensor], eps: float = 1e-8) -> torch.Tensor:
    """[B,X,Y,Z]: the share of the raw approach's length orthogonal to the baseline, i.e. how well
    the unit approach is defined (near 0 where the raw approach is nearly parallel to it)."""
    _, orthogonal = _unit_baseline_and_orthogonal_approach(out["baseline"], out["approach"], eps)
    return orthogonal.norm(dim=1) / out["approach"].norm(dim=1).clamp_min(eps)


class VgnExport(nn.Module):
    """``vgn.onnx``: activations in-graph, width in metres."""

    def __init__(self, net: VgnNet, voxel_size_m: float):
        super().__init__()
        self.net = net
        self.voxel_size_m = float(voxel_size_m)

    def heads(self, out: dict[str, torch.Tensor]):
        """The exported outputs (quality, unit baseline, unit approach, width in metres) from the
        net's raw heads."""
        b, a = orientation(out["baseline"], out["approach"])
        return torch.sigmoid(out["quality_logit"]), b, a, out["width_vox"] * self.voxel_size_m

    def forward(self, normal_grid: torch.Tensor):
        return self.heads(self.net(normal_grid))


def vgn_targets(scene: Scene, min_quality: float = MIN_LABEL_QUALITY, dilate: int = 0) -> dict[str, torch.Tensor]:
    """VGN targets of a scene: ``positive`` [X,Y,Z] bool, ``baseline``/``approach`` [3,X,Y,Z] and
    ``width`` [X,Y,Z] (m; zero at negatives).

    Candidates are all (configuration, approach) pairs with a collision-free approach and quality
    > ``min_quality``; the pair's voxel is the one holding its centre c + b·w/2. Per voxel the best
    quality wins, ties go to the approach closest to vertical, then to the lower configuration index
    (deterministic). ``dilate`` = d > 0 also makes every voxel within Chebyshev distance d of a
    centre voxel a positive carrying the best grasp centred in that neighbourhood."""
    dims = scene.dims
    nvox = dims[0] * dims[1] * dims[2]
    out = {"positive": torch.zeros(dims, dtype=torch.bool), "baseline": torch.zeros(3, *dims),
           "approach": torch.zeros(3, *dims), "width": torch.zeros(dims)}
    if len(scene.contact) == 0:
        return out
    ok = (scene.collision_free > 0.5) & (scene.quality > min_quality).unsqueeze(1)
    centre = scene.contact + scene.baseline * (0.5 * scene.width).unsqueeze(1)
    ijk = torch.floor(centre / scene.voxel_size_m).long()
    inside = ((ijk >= 0) & (ijk < torch.tensor(dims))).all(1)
    ok &= inside.unsqueeze(1)
    gi, ai = ok.nonzero(as_tuple=True)
    if len(gi) == 0:
        return out
    q = scene.quality[gi].double().numpy()
    order = np.lexsort((gi.numpy(), np.abs(ai.numpy() - _MID_APPROACH), -q))
    rank = torch.empty(len(gi), dtype=torch.long)
    rank[torch.from_numpy(order)] = torch.arange(len(gi))
    v = ijk[gi]
    if dilate > 0:
        r = torch.arange(-dilate, dilate + 1)
        offsets = torch.cartesian_prod(r, r, r)
        v = (v.unsqueeze(1) + offsets.unsqueeze(0)).reshape(-1, 3)
        keep = ((v >= 0) & (v < torch.tensor(dims))).all(1)
        n_off = len(offsets)
        gi, ai, rank = (x.repeat_interleave(n_off)[keep] for x in (gi, ai, rank))
        v = v[keep]
    lin = (v[:, 0] * dims[1] + v[:, 1]) * dims[2] + v[:, 2]
    best = torch.full((nvox,), torch.iinfo(torch.long).max, dtype=torch.long).scatter_reduce(0, lin, rank, "amin")
    win = rank == best[lin]
    gw, aw, lw = gi[win], ai[win], lin[win]
    b = scene.baseline[gw]
    b = b / b.norm(dim=1, keepdim=True)
    a = approach_vectors(b)[torch.arange(len(gw)), aw]
    pos = out["positive"].view(-1)
    pos[lw] = True
    out["baseline"].view(3, -1)[:, lw] = b.T
    out["approach"].view(3, -1)[:, lw] = a.T
    out["width"].view(-1)[lw] = scene.width[gw]
    return out


def negative_region(normals: torch.Tensor, band_voxels: int) -> torch.Tensor:
    """Voxels within ``band_voxels`` (Chebyshev distance) of an observed surface voxel (non-zero
    normal); every voxel for ``band_voxels`` = 0. ``normals`` [3, X, Y, Z] → [X, Y, Z] bool."""
    if band_voxels <= 0:
        return torch.ones(normals.shape[1:], dtype=torch.bool, device=normals.device)
    surface = (normals.abs().sum(0) > 0).float()[None, None]
    k = 2 * band_voxels + 1
    return F.max_pool3d(surface, k, stride=1, padding=band_voxels)[0, 0] > 0


def vgn_loss(out: dict[str, torch.Tensor], targets: dict[str, torch.Tensor], voxel_size_m: float,
             region: torch.Tensor | None = None, positive_weight: float = 0.0) -> dict:
    """Quality BCE over the positives and the negatives inside ``region`` (default every voxel):
    balanced (mean over positives + mean over negatives) for ``positive_weight`` = 0, else one
    weighted mean with that weight on positives; at positives the orientation loss
    (1 − |b̂·b|) + (1 − â·a) and 0.01 × width MSE in voxel units (VGN's weights)."""
    pos = targets["positive"].unsqueeze(0)
    logit = out["quality_logit"][:, 0]
    bce = F.binary_cross_entropy_with_logits(logit, pos.float(), reduction="none")
    neg = ~pos if region is None else (~pos) & region.unsqueeze(0)
    n_pos = int(pos.sum())
    zero = logit.sum() * 0
    if positive_weight > 0:
        q_loss = (positive_weight * bce[pos].sum() + bce[neg].sum()) / max(positive_weight * n_pos + int(neg.sum()), 1)
    else:
        q_loss = (bce[neg].mean() if bool(neg.any()) else zero) + (bce[pos].mean() if n_pos else zero)
    if n_pos == 0:
        return {"loss": q_loss, "quality": q_loss, "rotation": zero, "width": zero, "positives": 0.0}
    b_hat, a_hat = orientation(out["baseline"], out["approach"])
    m = pos[0]
    bp, ap = b_hat[0][:, m], a_hat[0][:, m]
    bt, at = targets["baseline"][:, m], targets["approach"][:, m]
    rot = ((1 - (bp * bt).sum(0).abs()) + (1 - (ap * at).sum(0))).mean()
    w = F.mse_loss(out["width_vox"][0, 0][m], targets["width"][m] / voxel_size_m)
    loss = q_loss + rot + WIDTH_WEIGHT * w
    return {"loss": loss, "quality": q_loss, "rotation": rot, "width": w, "positives": float(n_pos)}


def _to(t: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    return t if device.type == "cpu" else {k: v.to(device) for k, v in t.items()}


@torch.no_grad()
def evaluate_vgn(net: VgnNet, ds: SceneDataset, cfg: Config, device: torch.device, max_scenes: int = 0) -> dict:
    """Held-out metrics: precision/recall of positive voxels at quality 0.5 and 0.9, and at true
    positives the baseline angle error (sign-free), approach angle error and width error."""
    net.eval()
    entries = ds.val_entries[: max_scenes] if max_scenes > 0 else ds.val_entries
    counts = {t: [0, 0, 0] for t in (0.5, 0.9)}  # tp, predicted, true
    b_err, a_err, w_err = [], [], []
    for entry in entries:
        scene = ds.scene(entry)
        tg = vgn_targets(scene)
        out = net(scene.normals.unsqueeze(0).to(device))
        q = torch.sigmoid(out["quality_logit"][0, 0]).cpu()
        for t, c in counts.items():
            p = q >= t
            c[0] += int((p & tg["positive"]).sum())
            c[1] += int(p.sum())
            c[2] += int(tg["positive"].sum())
        m = tg["positive"]
        if bool(m.any()):
            b, a = orientation(out["baseline"].cpu(), out["approach"].cpu())
            b_err.append(torch.rad2deg(torch.acos((b[0][:, m] * tg["baseline"][:, m]).sum(0).abs().clamp(max=1))))
            a_err.append(torch.rad2deg(torch.acos((a[0][:, m] * tg["approach"][:, m]).sum(0).clamp(-1, 1))))
            w_err.append((out["width_vox"][0, 0].cpu()[m] * scene.voxel_size_m - tg["width"][m]).abs() * 1000)
    net.train()

    def mean(xs):
        return float(torch.cat(xs).mean()) if xs else 0.0

    res: dict[str, Any] = {"scenes": len(entries)}
    for t, (tp, npred, ntrue) in counts.items():
        res[f"precision@{t}"] = tp / npred if npred else 0.0
        res[f"recall@{t}"] = tp / ntrue if ntrue else 0.0
    res.update(positives=counts[0.5][2], baseline_angle_error_deg=mean(b_err), approach_angle_error_deg=mean(a_err),
               width_error_mm=mean(w_err))
    return res


def train_vgn(cfg: Config, data: Path, run_dir: Path, resume: bool = False, export: bool = True, log=print,
              stop_at: int | None = None) -> dict:
    """Train (or resume) a VGN-style run with the shared loop (:func:`psgrasp_training.train.fit`:
    same run-directory layout, schedule, seeds and flip augmentation); exports ``RUN/model``."""
    from .train import fit

    def step_fn(net, scene, _g, device, _step):
        targets = _to(vgn_targets(scene, dilate=cfg.loss.vgn_positive_dilation_voxels), device)
        normals = scene.normals.to(device)
        region = negative_region(normals, cfg.loss.vgn_negative_band_voxels)
        return vgn_loss(net(normals.unsqueeze(0)), targets, scene.voxel_size_m, region, cfg.loss.vgn_positive_weight)

    def progress(v):
        return (f"loss {v['loss']:.4f} quality {v['quality']:.4f} rotation {v['rotation']:.4f} "
                f"width {v['width']:.3f} positives {v['positives']:.0f}")

    return fit(cfg, data, run_dir, lambda c: VgnNet(c.model.base_channels), step_fn, evaluate_vgn, export_vgn,
               LOG_FIELDS, f"{cfg.model_name} (VGN-style)", progress, resume=resume, export=export, log=log,
               stop_at=stop_at)


def build_vgn_card(cfg: Config, info: DatasetInfo, step: int, validation: dict | None, sha: str,
                   elapsed_s: float | None = None) -> dict[str, Any]:
    """``card.json`` of a VGN-style model directory."""
    from .export import torch_version, training_time

    return {
        "format": VGN_CARD_FORMAT,
        "format_version": VGN_FORMAT_VERSION,
        "name": cfg.name or f"psgrasp-vgn-b{cfg.model.base_channels}",
        "variant": "vgn",
        "generator": f"psgrasp_training {__version__} (torch {torch_version()})",
        "files": {"vgn": {"path": "vgn.onnx", "sha256": sha}},
        "grid": {"dims": list(info.dims), "voxel_size_m": info.voxel_size_m, "input": "normals", "input_channels": 3},
        "gripper": {"max_opening_m": info.max_opening_m, "approach_depth_m": info.approach_depth_m},
        "network": {"channels": [cfg.model.base_channels * 2**i for i in range(3)]},
        "training": {"dataset_manifest_sha256": info.manifest_sha256, "dataset_path": info.path,
                     "scenes": info.train_scenes, "iterations": step, "seed": cfg.seed,
                     "time": training_time(cfg, elapsed_s), "config": cfg.to_dict()},
        "validation": validation,
    }


def export_vgn(net: VgnNet, cfg: Config, info: DatasetInfo, out_dir: Path, step: int = 0,
               validation: dict | None = None, reference_scene: Path | None = None,
               reference_normals: torch.Tensor | None = None, atol: float = 1e-5, rtol: float = 1e-5,
               log=print, elapsed_s: float | None = None) -> dict[str, Any]:
    """Export ``vgn.onnx`` + ``card.json`` (+ ``reference.safetensors`` for a reference input),
    checked with onnxruntime against PyTorch before the directory is renamed into place."""
    from safetensors.torch import save_file

    from .export import (ExportError, _check, _export_onnx, _ort_session, _random_normal_grid, move_into_place,
                         sha256_bytes)

    out_dir = Path(out_dir)
    net = net.cpu().eval()
    if reference_scene is not None:
        scene = read_scene(reference_scene)
        if scene.dims != list(info.dims):
            raise ExportError(f"reference scene {reference_scene} has grid {scene.dims}, the model {info.dims}")
        normal_grid = scene.normals.unsqueeze(0).contiguous()
    elif reference_normals is not None:
        normal_grid = reference_normals.reshape(1, 3, *info.dims).contiguous()
    else:
        normal_grid = _random_normal_grid(list(info.dims), cfg.seed)
    tmp_dir = out_dir.with_name(f".{out_dir.name}.tmp-{os.getpid()}")
    if tmp_dir.exists():
        shutil.rmtree(tmp_dir)
    tmp_dir.mkdir(parents=True)
    try:
        path = tmp_dir / "vgn.onnx"
        module = VgnExport(net, info.voxel_size_m).eval()
        with torch.no_grad():
            _export_onnx(module, (normal_grid,), path, ["normal_grid"], list(VGN_OUTPUTS), None)
            raw = net(normal_grid)
            ours = module.heads(raw)
            theirs = _ort_session(path).run(None, {"normal_grid": normal_grid.numpy()})
            share = approach_orthogonal_share(raw).numpy()
            baseline_length = raw["baseline"].norm(dim=1).clamp(max=1.0).numpy()
        diffs = []
        for name, o, t in zip(VGN_OUTPUTS, ours, theirs):
            o = o.numpy()
            if name == "baseline":
                # The same for the baseline where its raw length is short (a random input grid
                # reaches voxels the training never shaped): compare it scaled back.
                o, t = o * baseline_length[:, None], t * baseline_length[:, None]
            if name == "approach":
                # Normalising the raw approach's part orthogonal to the baseline magnifies float
                # rounding by 1 / its share of the length: compare the approach scaled back.
                o, t = o * share[:, None], t * share[:, None]
            diffs.append(_check(name, o, t, atol, rtol))
        diff = max(diffs)
        log(f"onnxruntime check passed: max abs diff {diff:.3g}")
        card = build_vgn_card(cfg, info, step, validation, sha256_bytes(path.read_bytes()), elapsed_s)
        card["export_check"] = {"onnxruntime_max_abs_diff": diff, "atol": atol, "rtol": rtol}
        (tmp_dir / "card.json").write_text(json.dumps(card, indent=2) + "\n")
        if reference_scene is not None or reference_normals is not None:
            tensors = {"normal_grid": normal_grid, **dict(zip(VGN_OUTPUTS, ours))}
            save_file({k: v.detach().float().contiguous() for k, v in tensors.items()},
                      str(tmp_dir / "reference.safetensors"),
                      metadata={"psgrasp_reference": json.dumps({"scene": str(reference_scene or "synthetic")})})
        move_into_place(tmp_dir, out_dir)
    finally:
        if tmp_dir.exists():
            shutil.rmtree(tmp_dir)
    return card


def export_vgn_run(run_dir: Path, out_dir: Path, reference_scene: Path | None = None, checkpoint: str = "latest.pt",
                   log=print) -> dict[str, Any]:
    """Export a checkpoint of a VGN-style run directory."""
    state = load_checkpoint(run_dir, checkpoint)
    cfg: Config = state["config"]
    net = VgnNet(cfg.model.base_channels)
    net.load_state_dict(state["model"])
    return export_vgn(net, cfg, state["dataset"], out_dir, state["step"], state.get("validation"), reference_scene,
                      log=log, elapsed_s=state.get("elapsed_s"))

