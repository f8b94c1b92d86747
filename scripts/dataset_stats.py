#!/usr/bin/env python3
"""Label statistics of a psgrasp dataset: grasps per scene / per (graspable) object and the
collision-free share of sampled gripper poses.

Usage: scripts/dataset_stats.py DATASET_DIR [--first N]
Needs numpy-free Python 3 only for the manifest figures; the uniform-pass share reads each scene's
metadata header (no tensors are loaded)."""
import argparse
import json
import os
import struct


def scene_metadata(path):
    # safetensors: 8-byte little-endian header length, then a JSON header with "__metadata__".
    with open(path, "rb") as f:
        (n,) = struct.unpack("<Q", f.read(8))
        header = json.loads(f.read(n))
    return json.loads(header["__metadata__"]["psgrasp_scene"])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--first", type=int, default=None, help="only the first N scenes")
    args = ap.parse_args()
    manifest = json.load(open(os.path.join(args.dataset, "manifest.json")))
    scenes = manifest["scenes"][: args.first]
    if not scenes:
        raise SystemExit("no finished scenes in the manifest")
    n = len(scenes)
    total = lambda key: sum(s[key] for s in scenes)
    grasps, objects, graspable = total("grasps"), total("objects"), total("graspable_objects")
    explore_checked = explore_free = 0
    for s in scenes:
        stats = scene_metadata(os.path.join(args.dataset, s["file"]))["label_stats"]
        explore_checked += stats["exploration_poses_checked"]
        explore_free += stats["exploration_poses_free"]
    print(f"scenes                                   {n}")
    print(f"grasps / scene                           {grasps / n:.0f}")
    print(f"grasp configurations / scene             {total('configurations') / n:.0f}")
    print(f"graspable objects / object               {graspable / max(objects, 1):.2f}")
    print(f"grasps / graspable object                {grasps / max(graspable, 1):.0f}")
    print(f"grasps / object                          {grasps / max(objects, 1):.0f}")
    print(f"free share, uniform pass                 {100 * explore_free / max(explore_checked, 1):.2f} %")
    print(f"free share, all poses checked            {100 * total('poses_free') / max(total('poses_checked'), 1):.2f} %")


if __name__ == "__main__":
    main()
