"""Scene datasets in the psgrasp dataset format (``docs/dataset-format.md``).

Only the tensors the network needs are read: ``normals``, ``label_grid`` and the grasp tensors
``grasp_contact``, ``grasp_baseline``, ``grasp_width``, ``grasp_quality``, ``grasp_collision_free``.
The train/validation split is by scene index (deterministic): every ``val_every``-th scene, or the
last ``val_scenes`` scenes, are held out.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import safe_open

from .checkpoint import DatasetInfo
from .config import Config
from .model import N_APPROACHES

#: Labelled grasps of at most this quality are not good grasps (the labeler keeps quality above
#: 0.5, the paper's rule; a dataset made with `failed_labels = "zero_quality"` also stores the
#: grasps that fail the physics check, with quality 0).
MIN_LABEL_QUALITY = 0.5

SCENE_TENSORS = ("normals", "label_grid", "grasp_contact", "grasp_baseline", "grasp_width", "grasp_quality",
                 "grasp_collision_free")


class DatasetError(ValueError):
    """A dataset directory or scene file is missing or malformed (the message names the file and tensor)."""


@dataclass
class Scene:
    """One training scene as torch tensors (CPU)."""

    normals: torch.Tensor  #: [3, X, Y, Z] float32
    labels: torch.Tensor  #: [X, Y, Z] int64 (0 empty, 1 contact, 2 gripper)
    contact: torch.Tensor  #: [G, 3] float32, m
    baseline: torch.Tensor  #: [G, 3] float32, unit
    width: torch.Tensor  #: [G] float32, m
    quality: torch.Tensor  #: [G] float32
    collision_free: torch.Tensor  #: [G, 18] float32 in {0, 1}
    voxel_size_m: float = 0.009
    index: int = 0
    meta: dict[str, Any] = field(default_factory=dict)
    #: [G] int64 object index of each grasp (`grasp_object`; None when the file has none).
    object: torch.Tensor | None = None

    @property
    def dims(self) -> list[int]:
        """Grid dims [X, Y, Z]."""
        return list(self.labels.shape)

    @property
    def extent_m(self) -> list[float]:
        """Grid extent per axis (m)."""
        return [d * self.voxel_size_m for d in self.dims]


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file."""
    h = hashlib.sha256()
    with Path(path).open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def read_scene(path: str | Path, index: int = 0) -> Scene:
    """Read one scene file; raises :class:`DatasetError` for missing tensors or inconsistent shapes."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"scene file {path} does not exist")
    try:
        with safe_open(str(path), "np") as f:
            keys = set(f.keys())
            missing = [k for k in SCENE_TENSORS if k not in keys]
            if missing:
                raise DatasetError(f"{path}: missing tensor(s) {missing}")
            arrays = {k: f.get_tensor(k) for k in SCENE_TENSORS}
            grasp_object = f.get_tensor("grasp_object") if "grasp_object" in keys else None
            meta = json.loads((f.metadata() or {}).get("psgrasp_scene", "{}"))
    except DatasetError:
        raise
    except Exception as e:  # noqa: BLE001 - safetensors raises several types for corrupt files
        raise DatasetError(f"{path}: cannot read safetensors file: {e}") from e
    normals = arrays["normals"]
    labels = arrays["label_grid"]
    if normals.ndim != 4 or normals.shape[0] != 3 or normals.dtype != np.float32:
        raise DatasetError(f"{path}: normals must be F32 [3,X,Y,Z], got {normals.dtype} {normals.shape}")
    if labels.shape != normals.shape[1:]:
        raise DatasetError(f"{path}: label_grid shape {labels.shape} differs from normals {normals.shape[1:]}")
    if labels.size and labels.max() > 2:
        raise DatasetError(f"{path}: label_grid holds class {labels.max()} (> 2)")
    g = arrays["grasp_contact"].shape[0]
    expect = {"grasp_contact": (g, 3), "grasp_baseline": (g, 3), "grasp_width": (g,), "grasp_quality": (g,),
              "grasp_collision_free": (g, N_APPROACHES)}
    for k, shape in expect.items():
        if arrays[k].shape != shape:
            raise DatasetError(f"{path}: {k} has shape {arrays[k].shape}, expected {shape}")
    voxel = float(meta.get("workspace", {}).get("voxel_size_m", 0.009))
    return Scene(
        normals=torch.from_numpy(np.ascontiguousarray(normals)),
        labels=torch.from_numpy(labels.astype(np.int64)),
        contact=torch.from_numpy(arrays["grasp_contact"].astype(np.float32)),
        baseline=torch.from_numpy(arrays["grasp_baseline"].astype(np.float32)),
        width=torch.from_numpy(arrays["grasp_width"].astype(np.float32)),
        quality=torch.from_numpy(arrays["grasp_quality"].astype(np.float32)),
        collision_free=torch.from_numpy(arrays["grasp_collision_free"].astype(np.float32)),
        voxel_size_m=voxel,
        index=index,
        meta=meta,
        object=torch.from_numpy(grasp_object.astype(np.int64)) if grasp_object is not None and len(grasp_object) == g
        else None,
    )


def flip_scene(scene: Scene, flip_x: bool, flip_y: bool) -> Scene:
    """Mirror a scene in x and/or y (grid axes, normal components, contacts, baselines).

    A mirror M that keeps z maps b⊥ to M b⊥ and turns rotations about b into rotations about Mb by
    −γ; −γ_i ≡ γ_{17−i} (mod 2π), so the collision flags are reversed per mirror (the hand is
    symmetric, so the collision status carries over). Labels and qualities are unchanged.
    """
    if not (flip_x or flip_y):
        return scene
    normals, labels = scene.normals, scene.labels
    contact, baseline, free = scene.contact.clone(), scene.baseline.clone(), scene.collision_free
    extent = scene.extent_m
    for axis, on in ((0, flip_x), (1, flip_y)):
        if not on:
            continue
        normals = normals.flip(axis + 1)
        normals = torch.cat([normals[:axis], -normals[axis:axis + 1], normals[axis + 1:]], dim=0)
        labels = labels.flip(axis)
        contact[:, axis] = extent[axis] - contact[:, axis]
        baseline[:, axis] = -baseline[:, axis]
        free = free.flip(1)
    return replace(scene, normals=normals.contiguous(), labels=labels.contiguous(), contact=contact,
                   baseline=baseline, collision_free=free.contiguous())


def crop_origin(scene: Scene, size: list[int], generator: torch.Generator, surface_share: float = 0.0) -> list[int]:
    """Voxel origin of a crop of `size` that holds a ground-truth contact voxel drawn at random
    (centred on it where the grid allows); a uniformly drawn origin in a scene without one.

    With `surface_share` > 0, that share of crops is centred on a random observed-surface voxel
    (non-zero normal) instead, contact or not. With 0 the generator draws exactly what it drew
    before the option existed (runs resume identically)."""
    dims = scene.dims
    room = [d - s for d, s in zip(dims, size)]
    if surface_share > 0 and float(torch.rand(1, generator=generator)) < surface_share:
        centres = torch.nonzero(scene.normals.abs().sum(0) > 0)
    else:
        centres = torch.nonzero(scene.labels == 1)
    if len(centres) == 0:
        return [int(torch.randint(r + 1, (1,), generator=generator)) for r in room]
    centre = centres[int(torch.randint(len(centres), (1,), generator=generator))].tolist()
    return [min(max(c - s // 2, 0), r) for c, s, r in zip(centre, size, room)]


def crop_scene(scene: Scene, origin: list[int], size: list[int]) -> Scene:
    """The box of `size` voxels from voxel `origin` as a scene of its own: the grids sliced, the
    grasps whose contact lies inside kept, with contacts in the crop's frame (origin at its corner).
    Baselines, widths, qualities and collision flags do not depend on the frame."""
    if any(o < 0 or o + s > d for o, s, d in zip(origin, size, scene.dims)):
        raise ValueError(f"crop {size} at {origin} leaves the grid {scene.dims}")
    (x0, y0, z0), (sx, sy, sz) = origin, size
    lo = torch.tensor(origin, dtype=torch.float32) * scene.voxel_size_m
    hi = torch.tensor([o + s for o, s in zip(origin, size)], dtype=torch.float32) * scene.voxel_size_m
    inside = ((scene.contact >= lo) & (scene.contact < hi)).all(1)
    return replace(
        scene,
        normals=scene.normals[:, x0:x0 + sx, y0:y0 + sy, z0:z0 + sz].contiguous(),
        labels=scene.labels[x0:x0 + sx, y0:y0 + sy, z0:z0 + sz].contiguous(),
        contact=scene.contact[inside] - lo,
        baseline=scene.baseline[inside],
        width=scene.width[inside],
        quality=scene.quality[inside],
        collision_free=scene.collision_free[inside],
        object=scene.object[inside] if scene.object is not None else None,
    )


class SceneDataset:
    """A psgrasp dataset directory with a deterministic train/validation split by scene index."""

    def __init__(self, root: str | Path, cfg: Config):
        self.root = Path(root)
        manifest_path = self.root / "manifest.json"
        if not manifest_path.is_file():
            raise DatasetError(f"{self.root} is not a psgrasp dataset (no manifest.json)")
        try:
            self.manifest = json.loads(manifest_path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise DatasetError(f"{manifest_path}: {e}") from e
        if self.manifest.get("format") != "psgrasp-dataset":
            raise DatasetError(f"{manifest_path}: format is {self.manifest.get('format')!r}, not 'psgrasp-dataset'")
        self.manifest_sha256 = sha256_file(manifest_path)
        entries = sorted(self.manifest.get("scenes", []), key=lambda e: e["index"])
        entries = [e for e in entries if (self.root / e["file"]).is_file()]
        if cfg.data.max_scenes > 0:
            entries = entries[: cfg.data.max_scenes]
        if not entries:
            raise DatasetError(f"{self.root}: no scene files listed in the manifest exist")
        if cfg.data.val_scenes >= 0:
            n_val = min(cfg.data.val_scenes, len(entries) - 1)
            self.train_entries = entries[: len(entries) - n_val]
            self.val_entries = entries[len(entries) - n_val:]
        else:
            k = cfg.data.val_every
            self.train_entries = [e for e in entries if e["index"] % k != k - 1]
            self.val_entries = [e for e in entries if e["index"] % k == k - 1]
            if not self.train_entries:
                self.train_entries, self.val_entries = self.val_entries, []
        conf = self.manifest.get("config", {})
        ws = conf.get("workspace", {})
        gr = conf.get("gripper", {})
        finger = gr.get("finger_size_m", [0.021, 0.026, 0.054])
        self.info = DatasetInfo(
            path=str(self.root.resolve()),
            manifest_sha256=self.manifest_sha256,
            dims=list(ws.get("dims", cfg.grid.dims)),
            voxel_size_m=float(ws.get("voxel_size_m", cfg.grid.voxel_size_m)),
            max_opening_m=float(gr.get("max_opening_m", cfg.grid.max_opening_m)),
            approach_depth_m=float(finger[2] - gr.get("tip_beyond_tcp_m", 0.015)) if gr else cfg.grid.approach_depth_m,
            train_scenes=len(self.train_entries),
            val_scenes=len(self.val_entries),
        )
        self.cache_enabled = cfg.data.cache
        self._cache: dict[int, Scene] = {}

    def scene(self, entry: dict[str, Any]) -> Scene:
        """Load (or fetch from the cache) the scene of a manifest entry."""
        idx = int(entry["index"])
        if idx in self._cache:
            return self._cache[idx]
        scene = read_scene(self.root / entry["file"], idx)
        if list(scene.dims) != list(self.info.dims) or abs(scene.voxel_size_m - self.info.voxel_size_m) > 1e-9:
            raise DatasetError(f"{entry['file']}: grid {scene.dims} @ {scene.voxel_size_m} m differs from the "
                               f"manifest's {self.info.dims} @ {self.info.voxel_size_m} m")
        if self.cache_enabled:
            self._cache[idx] = scene
        return scene
