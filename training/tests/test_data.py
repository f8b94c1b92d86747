import json

import numpy as np
import pytest
import torch
from safetensors.numpy import save_file

from psgrasp_training.data import DatasetError, SceneDataset, crop_origin, crop_scene, flip_scene, read_scene
from psgrasp_training.decode import approach_vectors
from synthetic import APPROACH_DEPTH, make_scene


def test_mirror_reverses_approach_order():
    g = torch.Generator().manual_seed(4)
    b = torch.randn(100, 3, generator=g, dtype=torch.float64)
    b = b / b.norm(dim=1, keepdim=True)
    a = approach_vectors(b)
    for axis in (0, 1):
        m = torch.ones(3, dtype=torch.float64)
        m[axis] = -1
        mirrored = approach_vectors(b * m)
        assert torch.allclose(a * m, mirrored.flip(1), atol=1e-9)


def scene_from_tensors(tmp_path, tensors, meta):
    path = tmp_path / "s.safetensors"
    save_file(tensors, str(path), metadata={"psgrasp_scene": json.dumps(meta)})
    return read_scene(path)


@pytest.mark.parametrize("fx,fy", [(True, False), (False, True), (True, True)])
def test_flip_keeps_normals_labels_and_grasps_consistent(tmp_path, fx, fy):
    tensors, meta = make_scene(0, np.random.default_rng(1), free_set=range(0, 6))  # asymmetric flags
    scene = scene_from_tensors(tmp_path, tensors, meta)
    f = flip_scene(scene, fx, fy)
    s = scene.voxel_size_m
    dims = torch.tensor(scene.dims)

    def label_at(sc, p):
        v = torch.floor(p / s).long().clamp(min=0)
        v = torch.minimum(v, dims - 1)
        return sc.labels[v[:, 0], v[:, 1], v[:, 2]]

    for sc in (scene, f):
        # Contacts lie in contact voxels; approach points of collision-free grasps in gripper/contact space.
        assert (label_at(sc, sc.contact) == 1).all()
        a = approach_vectors(sc.baseline)
        t = (sc.contact + 0.5 * sc.width[:, None] * sc.baseline)[:, None] - a * APPROACH_DEPTH
        free = sc.collision_free.bool()
        inside = ((t >= 0) & (t < dims * s)).all(-1)
        lab = label_at(sc, t[free & inside])
        assert (lab >= 1).all()
        # Normals point away from the box: at the contact voxel the normal opposes the baseline.
        v = torch.floor(sc.contact / s).long()
        n = sc.normals[:, v[:, 0], v[:, 1], v[:, 2]].t()
        assert ((n * sc.baseline).sum(1) < 0).float().mean() >= 0.85  # floor voxels excepted
    # One mirror reverses the flag order, two restore it.
    assert torch.equal(f.collision_free, scene.collision_free.flip(1) if fx != fy else scene.collision_free)


def test_read_scene_errors(tmp_path):
    tensors, meta = make_scene(0, np.random.default_rng(1))
    del tensors["grasp_width"]
    path = tmp_path / "bad.safetensors"
    save_file(tensors, str(path), metadata={"psgrasp_scene": json.dumps(meta)})
    with pytest.raises(DatasetError, match="grasp_width"):
        read_scene(path)
    (tmp_path / "junk.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(DatasetError, match="cannot read"):
        read_scene(tmp_path / "junk.safetensors")
    with pytest.raises(DatasetError, match="no manifest"):
        SceneDataset(tmp_path, None)


def test_split_is_deterministic_by_index(box_dataset, tiny_cfg):
    ds = SceneDataset(box_dataset, tiny_cfg())
    assert [e["index"] for e in ds.train_entries] == [0, 1]
    assert [e["index"] for e in ds.val_entries] == [2]
    assert ds.info.approach_depth_m == pytest.approx(0.039)
    assert ds.info.dims == [16, 16, 16]


def test_modulo_split(box_dataset, tiny_cfg):
    from psgrasp_training.config import config_from_dict

    cfg = config_from_dict({"data": {"val_every": 3}})
    ds = SceneDataset(box_dataset, cfg)
    assert [e["index"] for e in ds.train_entries] == [0, 1] and [e["index"] for e in ds.val_entries] == [2]


def test_crops_keep_labels_normals_and_grasps_aligned(tmp_path):
    tensors, meta = make_scene(0, np.random.default_rng(2))
    scene = scene_from_tensors(tmp_path, tensors, meta)
    s = scene.voxel_size_m
    size = [8, 8, 8]
    seen = 0
    for seed in range(12):
        origin = crop_origin(scene, size, torch.Generator().manual_seed(seed))
        assert all(0 <= o <= d - c for o, c, d in zip(origin, size, scene.dims))
        c = crop_scene(scene, origin, size)
        assert c.dims == size and c.extent_m == [8 * s] * 3
        x0, y0, z0 = origin
        assert torch.equal(c.labels, scene.labels[x0:x0 + 8, y0:y0 + 8, z0:z0 + 8])
        assert torch.equal(c.normals, scene.normals[:, x0:x0 + 8, y0:y0 + 8, z0:z0 + 8])
        # The crop holds a contact voxel and exactly the grasps whose contact lies in the box.
        assert (c.labels == 1).any()
        v = torch.floor(scene.contact / s).long()
        inside = ((v >= torch.tensor(origin)) & (v < torch.tensor(origin) + 8)).all(1)
        assert len(c.contact) == int(inside.sum()) > 0
        seen += len(c.contact)
        # Each kept contact sits in the same voxel of the crop as of the scene: label and normal agree.
        vc = torch.floor(c.contact / s).long()
        assert torch.equal(vc + torch.tensor(origin), v[inside])
        assert (c.labels[vc[:, 0], vc[:, 1], vc[:, 2]] == 1).all()
        assert torch.equal(c.normals[:, vc[:, 0], vc[:, 1], vc[:, 2]], scene.normals[:, v[inside, 0], v[inside, 1],
                                                                                     v[inside, 2]])
        assert torch.equal(c.baseline, scene.baseline[inside]) and torch.equal(c.width, scene.width[inside])
        assert torch.equal(c.collision_free, scene.collision_free[inside])
    assert seen > 0
    # The same generator seed gives the same crop.
    assert crop_origin(scene, size, torch.Generator().manual_seed(5)) == crop_origin(
        scene, size, torch.Generator().manual_seed(5))
    with pytest.raises(ValueError, match="leaves the grid"):
        crop_scene(scene, [10, 0, 0], size)


def test_surface_crops_centre_on_observed_surface_and_leave_contact_crops_unchanged(tmp_path):
    tensors, meta = make_scene(0, np.random.default_rng(2))
    scene = scene_from_tensors(tmp_path, tensors, meta)
    size = [8, 8, 8]
    surface = scene.normals.abs().sum(0) > 0
    half = torch.tensor([s // 2 for s in size])
    room = torch.tensor([d - s for d, s in zip(scene.dims, size)])
    for seed in range(12):
        # Share 1: every crop is centred on an observed-surface voxel (where the grid allows it).
        origin = torch.tensor(crop_origin(scene, size, torch.Generator().manual_seed(seed), surface_share=1.0))
        centres = torch.nonzero(surface)
        assert ((origin == (centres - half).clamp(min=0).minimum(room)).all(1)).any()
        # Share 0 draws what the contact crops always drew (a resumed run continues identically).
        a = crop_origin(scene, size, torch.Generator().manual_seed(seed))
        b = crop_origin(scene, size, torch.Generator().manual_seed(seed), surface_share=0.0)
        assert a == b
    # Surface crops reach voxels no contact crop is centred on (the floor, faces without contacts).
    contact_origins = {tuple(crop_origin(scene, size, torch.Generator().manual_seed(k))) for k in range(200)}
    surface_origins = {tuple(crop_origin(scene, size, torch.Generator().manual_seed(k), surface_share=1.0))
                       for k in range(200)}
    assert surface_origins - contact_origins


def test_crop_surface_share_is_checked(tiny_cfg):
    from psgrasp_training.config import ConfigError

    cfg = tiny_cfg()
    cfg.data.crop = [8, 8, 8]
    cfg.data.crop_surface_share = 0.5
    cfg.validate()
    for bad in (-0.1, 1.5):
        cfg.data.crop_surface_share = bad
        with pytest.raises(ConfigError, match="crop_surface_share"):
            cfg.validate()


def test_crop_sizes_are_checked_against_grid_and_levels(tiny_cfg):
    from psgrasp_training.config import ConfigError

    cfg = tiny_cfg()
    cfg.data.crop = [8, 8, 8]
    cfg.validate()
    for bad in ([8, 8], [8, 8, 32], [8, 8, 7]):
        cfg.data.crop = bad
        with pytest.raises(ConfigError, match="data.crop"):
            cfg.validate()
