"""A small analytic dataset in the psgrasp dataset format: one box on the floor per scene.

Grid 16³ voxels of 9 mm. The box (axis-aligned, size and position per scene) is grasped across its
x faces: contacts on a 3 mm lattice of each x face with baselines ±x, width = box x size, quality 1,
collision-free approaches i ∈ [3, 14] (both copies of each pair stored, flags of the second copy
reversed as in the dataset format). Normals: unit normals of the nearest box/floor point for voxels
within 1.5 voxels of a surface. Labels: contact voxels hold a contact, gripper voxels the approach
point of a collision-free grasp (contact wins).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from safetensors.numpy import save_file

VOXEL = 0.009
DIMS = (16, 16, 16)
MAX_OPENING = 0.08
FINGER = [0.021, 0.026, 0.054]
TIP = 0.015
APPROACH_DEPTH = FINGER[2] - TIP
FREE = range(3, 15)


def approach_vectors_np(b: np.ndarray) -> np.ndarray:
    """Independent numpy version of the dataset's approach vectors (Rodrigues), b [3] → [18, 3]."""
    b = b / np.linalg.norm(b)
    up = np.array([0.0, 0.0, 1.0])
    p = up - up.dot(b) * b
    if np.linalg.norm(p) < 1e-3:
        x = np.array([1.0, 0.0, 0.0])
        p = x - x.dot(b) * b
    p /= np.linalg.norm(p)
    out = []
    for i in range(18):
        g = math.pi / 2 + math.pi * i / 17
        out.append(p * math.cos(g) + np.cross(b, p) * math.sin(g) + b * b.dot(p) * (1 - math.cos(g)))
    return np.array(out)


def make_scene(index: int, rng: np.random.Generator, free_set=FREE) -> tuple[dict[str, np.ndarray], dict]:
    """Tensors and metadata of one scene (collision-free approaches `free_set` for the first copy of each pair)."""
    extent = np.array(DIMS) * VOXEL
    size = np.array([rng.uniform(0.03, 0.045), rng.uniform(0.03, 0.05), rng.uniform(0.03, 0.045)])
    centre_xy = extent[:2] / 2 + rng.uniform(-0.01, 0.01, 2)
    floor_z = 0.5 * VOXEL
    lo = np.array([centre_xy[0] - size[0] / 2, centre_xy[1] - size[1] / 2, floor_z])
    hi = lo + size

    idx = np.stack(np.meshgrid(*[np.arange(d) for d in DIMS], indexing="ij"), -1)
    centres = (idx + 0.5) * VOXEL
    nearest = np.clip(centres, lo, hi)
    d_box = np.linalg.norm(centres - nearest, axis=-1)
    n_box = (centres - nearest) / np.maximum(d_box, 1e-9)[..., None]
    d_floor = centres[..., 2] - floor_z
    normals = np.zeros((*DIMS, 3), np.float32)
    near_floor = (d_floor >= 0) & (d_floor < 1.5 * VOXEL) & (d_box > 0)
    normals[near_floor] = (0, 0, 1)
    near_box = (d_box > 0) & (d_box < 1.5 * VOXEL) & ((d_box <= d_floor) | ~near_floor)
    normals[near_box] = n_box[near_box]
    normals = np.ascontiguousarray(np.moveaxis(normals, -1, 0))

    contacts, baselines, widths, flags = [], [], [], []
    ys = np.arange(lo[1] + 0.003, hi[1] - 0.002, 0.003)
    zs = np.arange(lo[2] + 0.003, hi[2] - 0.002, 0.003)
    free = np.zeros(18, np.uint8)
    free[list(free_set)] = 1
    for y in ys:
        for z in zs:
            c1 = np.array([lo[0], y, z])
            c2 = np.array([hi[0], y, z])
            contacts += [c1, c2]
            baselines += [np.array([1.0, 0, 0]), np.array([-1.0, 0, 0])]
            widths += [size[0], size[0]]
            flags += [free, free[::-1]]
    contacts = np.array(contacts, np.float32)
    baselines = np.array(baselines, np.float32)
    widths = np.array(widths, np.float32)
    flags = np.array(flags, np.uint8)
    g = len(contacts)

    labels = np.zeros(DIMS, np.uint8)
    for c, b, w, f in zip(contacts, baselines, widths, flags):
        a = approach_vectors_np(b.astype(np.float64))
        tcp = c + 0.5 * w * b
        for i in np.nonzero(f)[0]:
            t = tcp - a[i] * APPROACH_DEPTH
            v = np.floor(t / VOXEL).astype(int)
            if np.all(v >= 0) and np.all(v < DIMS):
                labels[tuple(v)] = 2
    for c in contacts:
        v = np.clip(np.floor(c / VOXEL).astype(int), 0, np.array(DIMS) - 1)
        labels[tuple(v)] = 1

    tensors = {
        "normals": normals,
        "label_grid": labels,
        "tsdf": np.zeros(DIMS, np.float32),
        "grasp_contact": contacts,
        "grasp_baseline": baselines,
        "grasp_contact_normal": -baselines,
        "grasp_second_normal": baselines.copy(),
        "grasp_width": widths,
        "grasp_quality": np.ones(g, np.float32),
        "grasp_collision_free": flags,
        "grasp_object": np.zeros(g, np.uint32),
    }
    meta = {
        "format_version": 1,
        "generator": "psgrasp_training tests",
        "scene_index": index,
        "seed": index,
        "workspace": {"dims": list(DIMS), "voxel_size_m": VOXEL},
        "gripper": {"max_opening_m": MAX_OPENING, "finger_size_m": FINGER, "palm_size_m": [0.204, 0.063, 0.092],
                    "tip_beyond_tcp_m": TIP},
    }
    return tensors, meta


def write_dataset(root: Path, scenes: int, seed: int = 0) -> Path:
    """Write a dataset directory with `scenes` box scenes; returns root."""
    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    entries = []
    for i in range(scenes):
        tensors, meta = make_scene(i, rng)
        name = f"scene_{i:06d}.safetensors"
        save_file(tensors, str(root / name), metadata={"psgrasp_scene": json.dumps(meta)})
        entries.append({"index": i, "file": name, "seed": i, "objects": 1, "configurations": 0,
                        "grasps": int(len(tensors["grasp_width"])), "graspable_objects": 1})
    manifest = {
        "format": "psgrasp-dataset", "format_version": 1, "generator": "psgrasp_training tests", "run_seed": seed,
        "scenes_requested": scenes,
        "config": {"workspace": {"dims": list(DIMS), "voxel_size_m": VOXEL},
                   "gripper": {"max_opening_m": MAX_OPENING, "finger_size_m": FINGER,
                               "palm_size_m": [0.204, 0.063, 0.092], "tip_beyond_tcp_m": TIP}},
        "scenes": entries,
    }
    (root / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return root
