"""Export a run to ``unet.onnx`` + ``mlp.onnx`` + ``card.json`` (+ ``reference.safetensors``).

Both graphs are checked with onnxruntime against PyTorch before anything is written; the model
directory is written into a temporary sibling directory and renamed into place.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from . import FORMAT_VERSION, __version__
from .checkpoint import DatasetInfo, load_checkpoint
from .config import Config
from .data import read_scene
from .decode import (GAMMA_MAX, GAMMA_MIN, class_probabilities, contact_voxels, decode, grid_extent,
                     sample_features, subvoxel_points)
from .model import CLASSES, MLP_OUTPUTS, N_APPROACHES, GraspNet, MlpExport, UnetExport

ONNX_OPSET = 17
#: Maximum number of points stored in reference.safetensors.
REFERENCE_POINTS = 256


class ExportError(RuntimeError):
    """Export failed (ONNX/PyTorch mismatch, bad reference scene, unwritable output)."""


def sha256_bytes(data: bytes) -> str:
    """Hex sha256."""
    return hashlib.sha256(data).hexdigest()


def torch_version() -> str:
    """torch version without the local build suffix."""
    return torch.__version__.split("+")[0]


def _export_onnx(module: torch.nn.Module, args: tuple, path: Path, input_names: list[str], output_names: list[str],
                 dynamic_axes: dict | None) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(module, args, str(path), dynamo=False, opset_version=ONNX_OPSET, input_names=input_names,
                          output_names=output_names, dynamic_axes=dynamic_axes, do_constant_folding=True,
                          training=torch.onnx.TrainingMode.EVAL)


def _ort_session(path: Path):
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = max(1, torch.get_num_threads())
    opts.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def max_abs_diff(a: np.ndarray, b: np.ndarray) -> float:
    """max |a − b| (0 for empty arrays)."""
    if a.shape != b.shape:
        return math.inf
    return float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64)))) if a.size else 0.0


def _check(name: str, ours: np.ndarray, theirs: np.ndarray, atol: float, rtol: float) -> float:
    d = max_abs_diff(ours, theirs)
    scale = float(np.max(np.abs(ours))) if ours.size else 0.0
    if not d <= atol + rtol * scale:
        raise ExportError(f"onnxruntime and PyTorch disagree on {name}: max abs diff {d:.3g} "
                          f"(allowed {atol:g} + {rtol:g}·{scale:.3g})")
    return d


def training_time(cfg: Config, elapsed_s: float | None) -> dict[str, Any]:
    """The card's record of the training time: wall-clock seconds over all sittings, the device
    and threads, and for CPU runs the core-hours (wall-clock × threads)."""
    elapsed = float(elapsed_s or 0.0)
    return {"elapsed_s": round(elapsed, 1), "device": cfg.train.device, "threads": cfg.train.threads,
            "cpu_hours": round(elapsed * max(1, cfg.train.threads) / 3600.0, 3) if cfg.train.device == "cpu" else None}


def build_card(cfg: Config, info: DatasetInfo, step: int, validation: dict | None, unet_sha: str, mlp_sha: str,
               contact_probability: float | None = None, elapsed_s: float | None = None) -> dict[str, Any]:
    """The model card (network contract v1 schema)."""
    val = validation or {}
    return {
        "format": "psgrasp-model",
        "format_version": FORMAT_VERSION,
        "name": cfg.model_name,
        "variant": cfg.variant,
        "generator": f"psgrasp_training {__version__} (torch {torch_version()})",
        "files": {"unet": {"path": "unet.onnx", "sha256": unet_sha}, "mlp": {"path": "mlp.onnx", "sha256": mlp_sha}},
        "grid": {"dims": list(info.dims), "voxel_size_m": info.voxel_size_m, "input": "normals", "input_channels": 3},
        "classes": list(CLASSES),
        "unet": {"levels": cfg.model.levels, "channels": cfg.channels(),
                 "feature_outputs": [f"enc{level}" for level in range(cfg.model.levels)]},
        "mlp": {"feature_dim": cfg.feature_dim(), "hidden": list(cfg.model.mlp_hidden)},
        "kappa0": cfg.model.kappa0,
        "kappa_learned": cfg.kappa_learned,
        "approaches": {"count": N_APPROACHES, "gamma_min_rad": GAMMA_MIN, "gamma_max_rad": GAMMA_MAX},
        "gripper": {"max_opening_m": info.max_opening_m, "approach_depth_m": info.approach_depth_m},
        "thresholds": {
            "contact_probability": cfg.export.contact_probability if contact_probability is None else contact_probability,
            "quality": cfg.export.quality,
            "collision": cfg.export.collision,
        },
        "inference": {"subvoxels_per_contact": 8, "single_approach": cfg.single_approach},
        "training": {
            "dataset_manifest_sha256": info.manifest_sha256,
            "dataset_path": info.path,
            "scenes": info.train_scenes,
            "iterations": step,
            "seed": cfg.seed,
            "time": training_time(cfg, elapsed_s),
            "config": cfg.to_dict(),
        },
        "validation": {
            "scenes": int(val.get("scenes", 0)),
            "iou": {c: float(val.get("iou", {}).get(c, 0.0)) for c in CLASSES},
            "baseline_angle_error_deg": float(val.get("baseline_angle_error_deg", 0.0)),
            "width_error_mm": float(val.get("width_error_mm", 0.0)),
            "quality_mae": float(val.get("quality_mae", 0.0)),
        },
    }


def move_into_place(tmp_dir: Path, out_dir: Path) -> None:
    """Make a finished model directory world-readable and rename it over ``out_dir``."""
    for f in tmp_dir.iterdir():
        f.chmod(0o644)
    tmp_dir.chmod(0o755)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    os.replace(tmp_dir, out_dir)


def _random_normal_grid(dims: list[int], seed: int) -> torch.Tensor:
    """A plausible input for graph checks when no scene is given: unit normals on a random 10 % of voxels."""
    g = torch.Generator().manual_seed(seed)
    n = torch.randn((3, *dims), generator=g)
    n = n / n.norm(dim=0, keepdim=True).clamp_min(1e-6)
    mask = torch.rand(tuple(dims), generator=g) < 0.1
    return (n * mask).unsqueeze(0)


def export_model(net: GraspNet, cfg: Config, info: DatasetInfo, out_dir: Path, step: int = 0,
                 validation: dict | None = None, reference_scene: Path | None = None,
                 contact_probability: float | None = None, atol: float = 1e-5, rtol: float = 1e-5,
                 log=print, elapsed_s: float | None = None) -> dict[str, Any]:
    """Export, verify and write a model directory; returns the card (`elapsed_s`: the run's
    training time over all sittings, recorded in the card)."""
    out_dir = Path(out_dir)
    net = net.cpu().eval()
    extent = grid_extent(info.dims, info.voxel_size_m)
    if reference_scene is not None:
        scene = read_scene(reference_scene)
        if scene.dims != list(info.dims) or abs(scene.voxel_size_m - info.voxel_size_m) > 1e-9:
            raise ExportError(f"reference scene {reference_scene} has grid {scene.dims} @ {scene.voxel_size_m} m, "
                              f"the model {info.dims} @ {info.voxel_size_m} m")
        normal_grid = scene.normals.unsqueeze(0).contiguous()
    else:
        normal_grid = _random_normal_grid(list(info.dims), cfg.seed)
    threshold = cfg.export.contact_probability if contact_probability is None else contact_probability

    tmp_dir = out_dir.with_name(f".{out_dir.name}.tmp-{os.getpid()}")
    if tmp_dir.exists():
        shutil.rmtree(tmp_dir)
    tmp_dir.mkdir(parents=True)
    try:
        unet_names = ["label_logits"] + [f"enc{level}" for level in range(cfg.model.levels)]
        unet_path, mlp_path = tmp_dir / "unet.onnx", tmp_dir / "mlp.onnx"
        with torch.no_grad():
            # Fresh wrapper modules start in training mode and export restores that mode recursively: eval().
            _export_onnx(UnetExport(net.unet).eval(), (normal_grid,), unet_path, ["normal_grid"], unet_names, None)
            feat_example = torch.zeros(2, cfg.feature_dim())
            _export_onnx(MlpExport(net.mlp).eval(), (feat_example,), mlp_path, ["features"], list(MLP_OUTPUTS),
                         {"features": {0: "N"}, **{name: {0: "N"} for name in MLP_OUTPUTS}})

            # PyTorch forward on the reference input.
            net.eval()
            logits, encs = net.unet(normal_grid)
            probs = class_probabilities(logits)
            voxels = contact_voxels(probs[0, 1], threshold)
            points = subvoxel_points(voxels, info.dims, info.voxel_size_m)[:REFERENCE_POINTS]
            features = sample_features(encs, points, extent)
            mlp_out = net.mlp(features)
            dec = decode(probs, mlp_out, points, extent, info.approach_depth_m, cfg.single_approach)

            # Check the graphs with onnxruntime.
            sess = _ort_session(unet_path)
            ort_unet = sess.run(None, {"normal_grid": normal_grid.numpy()})
            diffs = {}
            for name, ours, theirs in zip(unet_names, [logits, *encs], ort_unet):
                diffs[name] = _check(name, ours.numpy(), theirs, atol, rtol)
            sess = _ort_session(mlp_path)
            g = torch.Generator().manual_seed(cfg.seed + 1)
            probe = torch.cat([features, torch.randn(3, cfg.feature_dim(), generator=g).abs()], dim=0)
            for batch in (probe[:1], probe):
                ours_mlp = net.mlp(batch)
                theirs = sess.run(None, {"features": batch.numpy()})
                for name, t in zip(MLP_OUTPUTS, theirs):
                    diffs[f"mlp.{name}"] = max(diffs.get(f"mlp.{name}", 0.0),
                                               _check(name, ours_mlp[name].numpy(), t, atol, rtol))
        log(f"onnxruntime check passed: max abs diff {max(diffs.values()):.3g} "
            f"({len(points)} reference points, threshold {threshold})")

        unet_sha = sha256_bytes(unet_path.read_bytes())
        mlp_sha = sha256_bytes(mlp_path.read_bytes())
        card = build_card(cfg, info, step, validation, unet_sha, mlp_sha, threshold, elapsed_s)
        card["export_check"] = {"onnxruntime_max_abs_diff": max(diffs.values()), "atol": atol, "rtol": rtol}
        (tmp_dir / "card.json").write_text(json.dumps(card, indent=2) + "\n")
        if reference_scene is not None:
            write_reference(tmp_dir / "reference.safetensors", normal_grid, logits, encs, points, features, mlp_out,
                            dec, {"scene": str(reference_scene), "contact_probability": threshold,
                                  "voxel_size_m": info.voxel_size_m, "dims": list(info.dims),
                                  "approach_depth_m": info.approach_depth_m, "single_approach": cfg.single_approach,
                                  "contact_voxels": int(voxels.numel()),
                                  "points_rule": "all voxels with P_contact >= threshold in ascending linear "
                                                 f"index, 8 sub-voxel centres each, first {REFERENCE_POINTS}"})
        move_into_place(tmp_dir, out_dir)
    finally:
        if tmp_dir.exists():
            shutil.rmtree(tmp_dir)
    return card


def write_reference(path: Path, normal_grid: torch.Tensor, logits: torch.Tensor, encs: list[torch.Tensor],
                    points: torch.Tensor, features: torch.Tensor, mlp_out: dict[str, torch.Tensor], dec,
                    meta: dict[str, Any]) -> None:
    """reference.safetensors (network contract v1) plus the decoded approach vectors/points."""
    from safetensors.torch import save_file

    tensors = {"normal_grid": normal_grid, "label_logits": logits}
    tensors.update({f"enc{level}": e for level, e in enumerate(encs)})
    tensors.update({"points": points, "features": features})
    tensors.update({name: mlp_out[name] for name in MLP_OUTPUTS})
    tensors.update({"quality": dec.quality, "collision_scores": dec.collision_scores,
                    "approach_vectors": dec.approach_vectors, "approach_points": dec.approach_points})
    tensors = {k: v.detach().to(torch.float32).contiguous() for k, v in tensors.items()}
    save_file(tensors, str(path), metadata={"psgrasp_reference": json.dumps(meta)})


#: Variants trained identically (they differ only at inference), so a run may be exported as either.
SAME_TRAINING = ("8app", "1app-kappa")


def export_run(run_dir: Path, out_dir: Path, reference_scene: Path | None = None,
               contact_probability: float | None = None, log=print, checkpoint: str = "latest.pt",
               variant: str | None = None) -> dict[str, Any]:
    """Export a checkpoint (default the latest) of a run directory, optionally as another variant
    with the same training (8app ↔ 1app-kappa)."""
    state = load_checkpoint(run_dir, checkpoint)
    cfg: Config = state["config"]
    if variant is not None and variant != cfg.variant:
        if cfg.variant not in SAME_TRAINING or variant not in SAME_TRAINING:
            raise ExportError(f"a {cfg.variant} run cannot be exported as {variant}: only {' and '.join(SAME_TRAINING)} "
                              "share their training")
        cfg.variant = variant
        cfg.name = ""
    net = GraspNet(cfg)
    net.load_state_dict(state["model"])
    return export_model(net, cfg, state["dataset"], out_dir, state["step"], state.get("validation"), reference_scene,
                        contact_probability, log=log, elapsed_s=state.get("elapsed_s"))
